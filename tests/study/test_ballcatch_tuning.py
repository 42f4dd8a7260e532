"""The learner selection's jobs and rule (analysis/selection/ballcatch_tuning.py,
docs/study/ballcatch/learner_selection.md)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from _helpers import compose_config

from analysis.selection import ballcatch_tuning as tuning
from sde_torchrl.config.schemas.train import validate


@pytest.mark.parametrize("method", list(tuning.METHODS))
@pytest.mark.e2e
def test_every_job_is_a_valid_config_with_the_rules_learner(method):
    alpha0 = tuning.METHODS[method][2]
    expected = {  # candidate → (return, optimiser class, lr, schedule, momentum)
        "C1": ("sum", "SGD", alpha0, "constant", 0.0), "C2": ("mean", "SGD", alpha0, "constant", 0.0),
        "C3": ("mean", "SGD", alpha0, "linear", 0.0), "C4": ("mean", "SGD", 10 * alpha0, "linear", 0.0),
        "C5": ("mean", "SGD", alpha0, "linear", 0.9), "C6": ("mean", "Adam", 1e-3, "linear", None),
        "C7": ("mean", "Adam", 3e-3, "linear", None), "C8": ("mean", "Adam", 1e-2, "linear", None),
        "C9": ("mean", "Adam", 3e-3, "linear", None),
    }
    assert list(expected) == tuning.ROUNDS[2]
    learns_sigma = tuning.METHODS[method][3]
    for candidate, (episode_return, optimizer, lr, schedule, momentum) in expected.items():
        conf = validate(compose_config(*tuning.job_overrides(method, candidate)))
        switched = candidate == "C9"  # round 2: C7 with σ̂'s learning switched
        assert conf.explorer.learn_sigma == (learns_sigma != switched), candidate
        assert conf.estimator.episode_return == episode_return, candidate
        assert conf.optimizer._target_ == f"torch.optim.{optimizer}", candidate
        assert conf.lr == pytest.approx(lr) and conf.optimizer.lr_schedule == schedule, candidate
        assert getattr(conf.optimizer, "momentum", None) == momentum, candidate
        assert (conf.seed, conf.runs, conf.updates, conf.episode_queue) == (1000, 8, 500, 20), candidate
        assert conf.env.model == "pybrain" and conf.explorer.squash, candidate


@pytest.mark.parametrize("method", list(tuning.METHODS))
@pytest.mark.e2e
def test_round_three_jobs_change_only_what_their_rule_says(method):
    """Round 3 (learner_selection.md, 2026-12-03): C7's learner with σ̂₀ = e⁻³ (C10), e⁻⁴ (C11) or
    the scaled observation (C12), beside C7 and C1; seed 3000, 16 runs."""
    learns_sigma = tuning.METHODS[method][3]
    c7 = validate(compose_config(*tuning.job_overrides(method, "C7", round_=3)))
    for candidate, init_param, observation in (("C10", -3.0, "raw"), ("C11", -4.0, "raw"), ("C12", -2.0, "scaled")):
        conf = validate(compose_config(*tuning.job_overrides(method, candidate, round_=3)))
        assert (conf.explorer.init_param, conf.env.observation) == (init_param, observation), candidate
        assert conf.explorer.learn_sigma == learns_sigma, candidate
        assert (conf.optimizer, conf.lr, conf.estimator) == (c7.optimizer, c7.lr, c7.estimator), candidate
    for candidate in tuning.ROUNDS[3]:
        conf = validate(compose_config(*tuning.job_overrides(method, candidate, round_=3)))
        assert (conf.seed, conf.runs, conf.updates, conf.env.model) == (3000, 16, 500, "pybrain"), candidate
    assert tuning.ROUNDS[3] == ["C7", "C1", "C10", "C11", "C12"]  # the rule's order, which breaks the last tie


@pytest.mark.parametrize("method", list(tuning.METHODS))
def test_round_four_adds_c10_with_sigma_fixed_on_round_three_s_seed(method):
    """Round 4 (learner_selection.md, 2026-12-04): C13 is C10's job with σ̂ fixed at e⁻³, on round
    3's seed and runs; for ENAC, whose command fixes σ̂ already, it is C10's job and is not run."""
    c10 = validate(compose_config(*tuning.job_overrides(method, "C10", round_=3)))
    c13 = validate(compose_config(*tuning.job_overrides(method, "C13", round_=4)))
    assert (c13.explorer.init_param, c13.explorer.learn_sigma) == (-3.0, False)
    assert (c13.seed, c13.runs, c13.updates) == (3000, 16, 500)
    assert (c13.optimizer, c13.lr, c13.estimator, c13.env) == (c10.optimizer, c10.lr, c10.estimator, c10.env)
    fixes_sigma = not tuning.METHODS[method][3]
    assert (c13 == c10) == fixes_sigma
    assert tuning.job_candidate(method, "C13") == ("C10" if fixes_sigma else "C13")
    assert [job.name for job in tuning.jobs(Path("t"), [method], ["C13"], round_=4)] == \
        ([] if fixes_sigma else [f"{method}/C13"])
    assert tuning.ROUNDS[4] == [*tuning.ROUNDS[3], "C13"]  # C13 wins only by beating round 3's choice


@pytest.mark.parametrize("method", list(tuning.METHODS))
def test_round_five_adds_c10_with_sigma_at_ten_times_the_rate(method):
    """Round 5 (learner_selection.md, 2026-12-05): C14 is C10's job with the exploration scale's
    parameters at 10 α, on round 3's seed and runs; for ENAC, whose command fixes σ̂, it is C10's
    job and is not run."""
    c10 = validate(compose_config(*tuning.job_overrides(method, "C10", round_=3)))
    c14 = validate(compose_config(*tuning.job_overrides(method, "C14", round_=5)))
    assert (c14.explorer.init_param, c14.optimizer.sigma_lr_factor, c10.optimizer.sigma_lr_factor) == (-3.0, 10, 1)
    assert (c14.seed, c14.runs, c14.updates) == (3000, 16, 500)
    assert (c14.explorer, c14.lr, c14.estimator, c14.env) == (c10.explorer, c10.lr, c10.estimator, c10.env)
    fixes_sigma = not tuning.METHODS[method][3]
    assert tuning.job_candidate(method, "C14") == ("C10" if fixes_sigma else "C14")
    assert [job.name for job in tuning.jobs(Path("t"), [method], ["C14"], round_=5)] == \
        ([] if fixes_sigma else [f"{method}/C14"])
    assert tuning.ROUNDS[5] == [*tuning.ROUNDS[4], "C14"]  # C14 wins only by beating round 4's choice


@pytest.mark.parametrize("method", list(tuning.METHODS))
def test_round_six_adds_c10_and_c1_with_queued_episodes_scored_as_collected(method):
    """Round 6 (learner_selection.md, 2026-12-06): C15 is C10's job and C16 C1's with
    ``queue_scores=as_collected``, on round 3's seed and runs, for every method (ENAC too: its
    controller's scores are kept; PGPE: its draws' scores under the distribution that drew
    them); nothing else changes."""
    for candidate, base, base_round in (("C15", "C10", 3), ("C16", "C1", 3)):
        before = validate(compose_config(*tuning.job_overrides(method, base, round_=base_round)))
        after = validate(compose_config(*tuning.job_overrides(method, candidate, round_=6)))
        assert (before.queue_scores, after.queue_scores) == ("rescored", "as_collected")
        assert (after.seed, after.runs, after.updates, after.episode_queue) == (3000, 16, 500, 20)
        assert (after.explorer, after.lr, after.estimator, after.env, after.optimizer) == \
            (before.explorer, before.lr, before.estimator, before.env, before.optimizer)
        names = [job.name for job in tuning.jobs(Path("t"), [method], [candidate], round_=6)]
        assert names == [f"{method}/{candidate}"]
    assert tuning.ROUNDS[6] == [*tuning.ROUNDS[5], "C15", "C16"]  # they win only by beating round 5's choice


@pytest.mark.parametrize("method", list(tuning.METHODS))
def test_round_seven_adds_c10_at_a_larger_step(method):
    """Round 7 (learner_selection.md, 2026-12-06): C17 is C10's job at Adam α = 1e-2, on round 3's
    seed and runs, for every method."""
    c10 = validate(compose_config(*tuning.job_overrides(method, "C10", round_=3)))
    c17 = validate(compose_config(*tuning.job_overrides(method, "C17", round_=7)))
    assert (c10.lr, c17.lr) == (0.003, 0.01)
    assert (c17.seed, c17.runs, c17.updates) == (3000, 16, 500)
    assert (c17.explorer, c17.estimator, c17.env, c17.optimizer, c17.queue_scores) == \
        (c10.explorer, c10.estimator, c10.env, c10.optimizer, c10.queue_scores)
    assert [job.name for job in tuning.jobs(Path("t"), [method], ["C17"], round_=7)] == [f"{method}/C17"]
    assert tuning.ROUNDS[7] == [*tuning.ROUNDS[6], "C17"]  # C17 wins only by beating round 6's choice


def test_round_four_chooses_once_its_six_jobs_have_run(tmp_path):
    import shutil

    from _helpers import REPO

    committed = REPO / "results" / "ballcatch" / "tuning" / "round3" / "reinforce_sde"
    folder = tmp_path / "round3" / "reinforce_sde"
    for candidate in tuning.ROUNDS[3]:
        shutil.copytree(committed / candidate, folder / candidate)
    numbers = tuning.round3_numbers(tmp_path / "round3")["methods"]["reinforce_sde"]
    assert (numbers["chosen"], numbers["chosen_round4"]) == ("C10", None)
    shutil.copytree(committed / "C10", folder / "C13")  # equal to C10: the tie goes to the earlier candidate
    assert tuning.round3_numbers(tmp_path / "round3")["methods"]["reinforce_sde"]["chosen_round4"] == "C10"
    shutil.rmtree(folder / "C13")
    shutil.copytree(REPO / "results" / "ballcatch" / "tuning" / "round3" / "enac_sde" / "C10", folder / "C13")
    numbers = tuning.round3_numbers(tmp_path / "round3")["methods"]["reinforce_sde"]  # 13 catches to C10's 12
    assert (numbers["chosen"], numbers["chosen_round4"]) == ("C10", "C13")
    text = "\n".join(tuning.round3_markdown(tuning.round3_numbers(tmp_path / "round3")))
    assert "Round 4 changes the choice of: REINFORCE + SDE C10 → C13" in text


def test_round_three_counts_good_catches_before_the_mean():
    results = {"C7": [-1.05, -1.05, -2.0], "C1": [-0.99, -1.09, -2.9], "C10": None}
    assert tuning.select(results) == "C7" and tuning.select(results, good_catches=True) == "C1"


def test_selection_counts_catches_then_mean_then_order():
    assert tuning.select({"C1": [-1.2, -1.2], "C2": [-1.05, -3.0], "C3": [-1.09, -2.5]}) == "C3"
    assert tuning.select({"C1": [-1.05, -2.0], "C2": [-1.05, -2.0]}) == "C1"
    assert tuning.select({"C1": None, "C2": [-2.9, -2.9]}) == "C2"
    assert tuning.select({"C1": None}) is None


@pytest.mark.parametrize("method, experiment, round_", [
    ("reinforce_sde", "ballcatch_reinforce", 3), ("reinforce_rex", "ballcatch_rex", 3),
    ("enac_sde", "ballcatch_enac", 6), ("enac_rex", "ballcatch_enac_rex", 3), ("gpomdp_sde", "ballcatch_gpomdp", 6),
    ("pgpe", "ballcatch_pgpe", 4),
])
def test_the_shipped_experiment_is_the_chosen_candidate(method, experiment, round_):
    """+experiment=ballcatch_reinforce (ballcatch_rex, ...) is the candidate docs/study/ballcatch/tuning.json chose
    in the round whose rerun sweep is committed (REINFORCE with SDE and REX and ENAC + REX: round
    3's, which the later rounds kept; PGPE: round 4's; ENAC + SDE and GPOMDP + SDE: round 6's),
    but for the tuning job's own seed, runs and bookkeeping, and the final check a user's job ends
    with (final_episodes), which trains nothing."""
    from _helpers import REPO
    from omegaconf import OmegaConf

    numbers = json.loads((REPO / "docs" / "study" / "ballcatch" / "tuning.json").read_text())
    methods = (numbers["round3"] if round_ >= 3 else numbers)["methods"]
    chosen = methods[method][tuning.LATER_ROUNDS[round_][0] if round_ >= 3 else "chosen"]
    tuning_only = ("seed", "runs", "first_run", "eval_period", "checkpoint_period", "logger", "final_episodes")
    job = [o for o in tuning.job_overrides(method, chosen, round_=round_) if o.split("=")[0] not in tuning_only]

    def resolved(*overrides):
        config = OmegaConf.to_container(compose_config(*overrides), resolve=True)
        return {k: v for k, v in config.items() if k not in tuning_only}

    assert resolved(f"+experiment={experiment}") == resolved(*job)


@pytest.mark.parametrize("method, experiment, shard", [("reinforce_sde", "ballcatch_sigma3_sweep", 50),
                                                       ("reinforce_rex", "ballcatch_rex_scaled_sweep", 50),
                                                       ("enac_sde", "ballcatch_enac_sigma3_sweep", 50),
                                                       ("gpomdp_sde", "ballcatch_gpomdp_sigma3_sweep", 25)])
def test_the_rerun_sweep_is_round_three_s_choice_on_the_rules_seed(method, experiment, shard):
    """The reported rerun at a method's round-3 choice: that candidate's job but on seed 3, in
    2 shards (learner_selection.md, round 3, "What follows"; GPOMDP's sweeps are of 50 runs)."""
    from _helpers import REPO
    from omegaconf import OmegaConf

    numbers_file = REPO / "docs" / "study" / "ballcatch" / "tuning.json"
    chosen = json.loads(numbers_file.read_text())["round3"]["methods"][method]
    tuning_only = ("seed", "runs", "first_run", "eval_period", "checkpoint_period", "logger")
    job = [o for o in tuning.job_overrides(method, chosen["chosen"], round_=3) if o.split("=")[0] not in tuning_only]
    sweep = OmegaConf.to_container(compose_config(f"+experiment={experiment}", f"first_run={shard}"),
                                   resolve=True)
    candidate = OmegaConf.to_container(compose_config(*job), resolve=True)
    assert {k: v for k, v in sweep.items() if k not in tuning_only} == \
        {k: v for k, v in candidate.items() if k not in tuning_only}
    assert (sweep["seed"], sweep["runs"], sweep["eval_period"]) == (3, shard, 20)


def test_the_round_four_rerun_sweep_is_round_four_s_choice_on_seed_4():
    """PGPE's round-4 choice differs from round 3's: its rerun is the chosen job on seed 4, as
    many runs as its reported sweep (learner_selection.md, round 4, "What follows")."""
    from _helpers import REPO
    from omegaconf import OmegaConf

    numbers_file = REPO / "docs" / "study" / "ballcatch" / "tuning.json"
    chosen = json.loads(numbers_file.read_text())["round3"]["methods"]["pgpe"]
    assert chosen["chosen_round4"] != chosen["chosen"]
    tuning_only = ("seed", "runs", "first_run", "eval_period", "checkpoint_period", "logger")
    job = [o for o in tuning.job_overrides("pgpe", chosen["chosen_round4"], round_=4)
           if o.split("=")[0] not in tuning_only]
    sweep = OmegaConf.to_container(compose_config("+experiment=ballcatch_pgpe_sigma3_fixed_sweep", "first_run=25"),
                                   resolve=True)
    candidate = OmegaConf.to_container(compose_config(*job), resolve=True)
    assert {k: v for k, v in sweep.items() if k not in tuning_only} == \
        {k: v for k, v in candidate.items() if k not in tuning_only}
    assert (sweep["seed"], sweep["runs"], sweep["eval_period"]) == (4, 25, 20)


def test_a_failed_job_is_shown_failed_and_counts_no_catch(tmp_path):
    import shutil

    from _helpers import REPO

    committed = REPO / "results" / "ballcatch" / "tuning" / "round3" / "reinforce_sde"
    folder = tmp_path / "round3" / "reinforce_sde"
    for candidate in tuning.ROUNDS[4]:
        shutil.copytree(committed / candidate, folder / candidate)
    (folder / "C10" / "summary.json").unlink()  # the round-3 and round-4 choice, failed
    (folder / "C10" / "error.txt").write_text("NonFiniteError: ...\n")
    numbers = tuning.round3_numbers(tmp_path / "round3")
    method = numbers["methods"]["reinforce_sde"]
    assert method["failed"] == ["C10"] and "C10" not in (method["chosen"], method["chosen_round4"])
    assert "| C10: C7, σ̂₀ = e⁻³ | failed |" in "\n".join(tuning.round3_markdown(numbers))


def test_a_method_is_chosen_for_only_once_its_whole_grid_has_run(tmp_path):
    import shutil

    from _helpers import REPO

    committed = REPO / "results" / "ballcatch" / "tuning" / "reinforce_sde"
    for candidate in ("C1", "C7"):
        shutil.copytree(committed / candidate, tmp_path / "tuning" / "reinforce_sde" / candidate)
    numbers = tuning.report(tmp_path / "tuning", tmp_path / "out")
    assert numbers["methods"]["reinforce_sde"]["chosen"] is None
    assert numbers["methods"]["reinforce_sde"]["candidates"]["C7"]["catches"] == 6
    text = (tmp_path / "out" / "tuning.md").read_text()
    assert "Not chosen yet in round 1, its candidates not all run: REINFORCE + SDE." in text


def test_round_two_chooses_among_all_nine_and_leaves_round_one_as_it_was(tmp_path):
    import shutil

    from _helpers import REPO

    committed = REPO / "results" / "ballcatch" / "tuning" / "reinforce_sde"
    for candidate in tuning.ROUNDS[1]:
        shutil.copytree(committed / candidate, tmp_path / "tuning" / "reinforce_sde" / candidate)
    numbers = tuning.report(tmp_path / "tuning", tmp_path / "out")["methods"]["reinforce_sde"]
    assert (numbers["chosen"], numbers["chosen_round2"]) == ("C7", None)
    c9 = tmp_path / "tuning" / "reinforce_sde" / "C9"
    shutil.copytree(committed / "C7", c9)  # C9 equal to C7: the tie goes to the earlier candidate
    assert tuning.report(tmp_path / "tuning", tmp_path / "out")["methods"]["reinforce_sde"]["chosen_round2"] == "C7"
    shutil.rmtree(c9)
    shutil.copytree(committed.parent / "enac_sde" / "C8", c9)  # a finished job with 7 final catches to C7's 6
    numbers = tuning.report(tmp_path / "tuning", tmp_path / "out")["methods"]["reinforce_sde"]
    assert (numbers["chosen"], numbers["chosen_round2"]) == ("C7", "C9")
    assert "Round 2 changes the choice of: REINFORCE + SDE C7 → C9." in (tmp_path / "out" / "tuning.md").read_text()


def test_run_leaves_a_finished_job_as_it_is(tmp_path):
    import shutil

    from _helpers import REPO

    job = tmp_path / "reinforce_sde" / "C1"
    shutil.copytree(REPO / "results" / "ballcatch" / "tuning" / "reinforce_sde" / "C1", job)
    before = {p.name: p.read_bytes() for p in job.iterdir() if p.is_file()}
    assert tuning.main(["run", "--out", str(tmp_path), "--methods", "reinforce_sde", "--candidates", "C1"]) == 0
    assert {p.name: p.read_bytes() for p in job.iterdir() if p.is_file()} == before
