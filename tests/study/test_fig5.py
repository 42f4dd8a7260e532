"""analysis/paper/fig5.py: catch counts from evaluation curves, merging shards of a sweep."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from _helpers import REPO, run_cli

from analysis.paper import fig5


def _write_job(directory: Path, explorer: str, first_run: int, evals: list[list[float]],
               summed_over: int | None = None, estimator: str = "reinforce",
               sigmas: list[tuple[float, float]] | None = None) -> None:
    """A run directory as train.py writes it: evaluations every 20 updates; with ``summed_over=T``,
    as a job with ``estimator.episode_return=sum`` over ``T`` steps reports the same returns; with
    ``sigmas``, per run the exploration scales (smallest, largest) start at 0.135 and shrink
    geometrically to those values at the last update (without: a job from before they were recorded)."""
    factor = summed_over or 1
    directory.mkdir(parents=True)
    fields = ["run", "update", "episodes", "return_mean", "eval_return"]
    with open(directory / "metrics.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields + (["grad_norm", "sigma_min", "sigma_max"] if sigmas else []))
        writer.writeheader()
        last = 20 * len(evals[0]) - 1
        for update in range(last + 1):  # the job's order: every run's row of an update, update by update
            i = update // 20
            for offset, curve in enumerate(evals):
                row = {"run": first_run + offset, "update": update, "episodes": update + 20,
                       "return_mean": -2.0, "eval_return": factor * curve[i] if update == 20 * i + 19 else ""}
                if sigmas:  # the columns in the job's order (grad_norm comes before them)
                    row["grad_norm"] = ""
                    row["sigma_min"], row["sigma_max"] = (0.135 * (end / 0.135) ** (update / last)
                                                          for end in sigmas[offset])
                writer.writerow(row)
    summary = {"estimator": estimator, "explorer": explorer, "first_run": first_run, "runs": len(evals),
               "updates_done": 20 * len(evals[0]), "final_eval_return": [factor * curve[-1] for curve in evals]}
    if summed_over:
        summary |= {"episode_return": "sum", "settings": {"episode_length": summed_over}}
    (directory / "summary.json").write_text(json.dumps(summary))


CURVES = {"sde": [[-2.5, -0.95, -1.05], [-2.5, -1.4, -1.2], [-3.0, -2.1, -1.6], [-1.8, -1.09, -1.3]],
          "rex": [[-3.0, -2.5, -1.9], [-2.2, -1.45, -1.6], [-3.0, -3.0, -3.0], [-2.4, -2.0, -0.99]]}


def test_counts_best_and_final_levels(tmp_path):
    for explorer, curves in CURVES.items():
        _write_job(tmp_path / explorer, explorer, 0, curves)
    assert fig5.main([str(tmp_path), "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "fig5.json").read_text())
    sde, rex = result["explorers"]["sde"], result["explorers"]["rex"]
    assert sde["best"] == {"-2.0": 4, "-1.5": 3, "-1.1": 2, "-1.0": 1}
    assert sde["final"] == {"-2.0": 4, "-1.5": 3, "-1.1": 1, "-1.0": 0}
    assert rex["best"] == {"-2.0": 3, "-1.5": 2, "-1.1": 1, "-1.0": 1}
    assert sde["paper"] == {"-1.0": 68, "-1.1": 98} and sde["runs"] == 4
    assert (tmp_path / "out" / "fig5.png").stat().st_size > 0
    assert "(paper 68 %)" in (tmp_path / "out" / "fig5.md").read_text()


def test_the_first_evaluation_is_counted_beside_the_final_one(tmp_path):
    """What training added: the runs at each level at the first evaluation (after 20 updates)."""
    curves = [[-1.05, -1.2, -0.95], [-0.98, -1.3, -1.5], [-2.5, -1.0, -1.0]]
    _write_job(tmp_path / "sde", "sde", 0, curves)
    assert fig5.main([str(tmp_path), "--out", str(tmp_path / "out")]) == 0
    first = json.loads((tmp_path / "out" / "fig5.json").read_text())["explorers"]["sde"]["first_evaluation"]
    assert first == {"update": 20, "reached": {"-2.0": 2, "-1.5": 2, "-1.1": 2, "-1.0": 1}}
    assert ("SDE: at the first evaluation, after 20 updates, a catch (R ≥ -1.1) in 67 % of runs and a good catch "
            "(R ≥ -1.0) in 33 %; at the final one 67 % and 67 %") in (tmp_path / "out" / "fig5.md").read_text()


def test_how_steadily_runs_stay_at_a_catch_is_the_mean_share_of_later_catching_evaluations(tmp_path):
    curves = [[-1.05, -1.2, -0.95], [-0.98, -1.3, -1.5], [-2.5, -1.0, -1.0], [-2.0, -1.8, -1.05]]
    _write_job(tmp_path / "sde", "sde", 0, curves)
    assert fig5.main([str(tmp_path), "--out", str(tmp_path / "out")]) == 0
    held = json.loads((tmp_path / "out" / "fig5.json").read_text())["explorers"]["sde"]["catch_held"]
    assert held == {"share": pytest.approx((0.5 + 0.0 + 1.0) / 3), "runs": 3}  # the last run's only catch is its last
    assert ("SDE: once at a catch: of the 3 runs whose evaluation reached a catch (R ≥ -1.1) before the last, "
            "the evaluations after the first such one are catches too in 50 % on average") in (
        tmp_path / "out" / "fig5.md").read_text()


def test_collapsed_exploration_is_counted_with_its_first_update(tmp_path):
    # 60 updates each; σ = 0.135 (end/0.135)^(u/59) first falls below 1e-3 where u > 59 ln(135)/ln(0.135/end).
    sigmas = [(1e-6, 1e-4), (1e-5, 0.2), (0.05, 0.3), (1e-4, 1e-4)]
    _write_job(tmp_path / "sde", "sde", 0, CURVES["sde"], sigmas=sigmas)
    _write_job(tmp_path / "rex", "rex", 0, CURVES["rex"])  # written before the columns existed
    assert fig5.main([str(tmp_path), "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "fig5.json").read_text())
    collapse = result["explorers"]["sde"]["collapse"]
    first = [int(59 * math.log(135) / math.log(0.135 / end)) + 2 for end in (1e-6, 1e-5, 1e-4)]  # 1-based
    assert collapse["recorded"] == 4 and collapse["level"] == 1e-3
    assert collapse["any"] == {"runs": 3, "median_update": sorted(first)[1], "first_update": min(first),
                               "last_update": max(first)}
    assert collapse["all"]["runs"] == 2  # runs 0 and 3: their largest scale fell too
    assert result["explorers"]["rex"]["collapse"] is None
    assert "SDE: exploration collapsed: 3 of 4 runs with some exploration scale below 0.001" in (
        tmp_path / "out" / "fig5.md").read_text()


def test_counts_carry_intervals_and_the_sde_rex_difference_its_significance(tmp_path):
    from sde_torchrl.utils.intervals import binomial_interval

    many = {"sde": [[-2.0, -0.95]] * 30 + [[-2.0, -2.4]] * 10, "rex": [[-2.0, -1.3]] * 36 + [[-2.5, -0.98]] * 4}
    for explorer, curves in many.items():
        _write_job(tmp_path / explorer, explorer, 0, curves)
    assert fig5.main([str(tmp_path), "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "fig5.json").read_text())
    sde = result["explorers"]["sde"]
    assert sde["best"]["-1.0"] == 30 and sde["best_interval"]["-1.0"] == pytest.approx(binomial_interval(30, 40)[1:])
    catch, slowed = result["sde_minus_rex"]["best"]["-1.0"], result["sde_minus_rex"]["best"]["-2.0"]
    assert catch["estimate"] == pytest.approx(0.75 - 0.1) and catch["significant"]
    assert catch["interval"][0] < 0.65 < catch["interval"][1]
    assert slowed["estimate"] == 0 and not slowed["significant"]  # every run of both reached -2.0
    table = (tmp_path / "out" / "fig5.md").read_text()
    assert "75 % [60, 86]" in table and "+65 [" in table and "]*" in table


def test_method_comparison_labels_each_estimator_and_differs_from_reinforce_sde(tmp_path):
    jobs = {("sde", "reinforce"): [[-2.0, -0.95]] * 8 + [[-2.0, -2.4]] * 2,
            ("rex", "reinforce"): [[-2.0, -1.3]] * 10,
            ("sde", "gpomdp"): [[-2.0, -0.95]] * 3 + [[-2.0, -1.6]] * 7,
            ("pgpe", "pgpe"): [[-2.0, -1.05]] * 10,
            ("sde", "enac"): [[-2.0, -0.9]] * 10}  # another figure's: left out
    for (explorer, estimator), curves in jobs.items():
        _write_job(tmp_path / f"{explorer}_{estimator}", explorer, 0, curves, estimator=estimator)
    assert fig5.main([str(tmp_path), "--estimator", "all", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "methods.json").read_text())
    assert sorted(result["explorers"]) == ["pgpe", "rex", "sde", "sde+gpomdp"]
    assert result["explorers"]["sde+gpomdp"]["best"]["-1.0"] == 3
    assert result["explorers"]["pgpe"]["best"] == {"-2.0": 10, "-1.5": 10, "-1.1": 10, "-1.0": 0}
    gpomdp = result["differences"]["sde+gpomdp − sde"]["best"]["-1.0"]
    assert gpomdp["estimate"] == pytest.approx(0.3 - 0.8)
    assert result["differences"]["pgpe − rex"]["best"]["-1.1"]["estimate"] == pytest.approx(1.0)
    table = (tmp_path / "out" / "methods.md").read_text()
    assert "| SDE+GPOMDP | 10 |" in table and "| PGPE − SDE (points) |" in table
    assert (tmp_path / "out" / "methods.png").stat().st_size > 0


def test_initial_evaluations_give_the_mean_change_per_run(tmp_path):
    curves = CURVES["sde"]  # finals -1.05, -1.2, -1.6, -1.3
    _write_job(tmp_path / "sde", "sde", 0, curves)
    initial = {"explorer": "sde", "estimator": "reinforce", "first_run": 0, "initial_eval_return": [-2.0, -2.5]}
    (tmp_path / "sde" / "initial_a").mkdir()
    (tmp_path / "sde" / "initial_a" / "initial.json").write_text(json.dumps(initial))
    assert fig5.main([str(tmp_path), "--out", str(tmp_path / "part")]) == 0
    assert json.loads((tmp_path / "part" / "fig5.json").read_text())["explorers"]["sde"]["improvement"] is None
    (tmp_path / "sde" / "initial_b").mkdir()
    (tmp_path / "sde" / "initial_b" / "initial.json").write_text(json.dumps(initial | {"first_run": 2}))
    assert fig5.main([str(tmp_path), "--out", str(tmp_path / "all")]) == 0
    change = json.loads((tmp_path / "all" / "fig5.json").read_text())["explorers"]["sde"]["improvement"]
    assert change["initial_mean"] == pytest.approx(-2.25) and change["final_mean"] == pytest.approx(-1.2875)
    assert change["change"][0] == pytest.approx(0.9625) and change["change"][1] <= 0.9625 <= change["change"][2]
    assert "mean change per run +0.96" in (tmp_path / "all" / "fig5.md").read_text()


def test_initial_evaluation_of_a_summed_return_job_is_in_mean_rewards(tmp_path):
    """The same Θ0 and release jitter, regressed on sums or means: the same mean-reward returns."""
    from analysis.paper import ballcatch_initial as initial
    tiny = ["+experiment=ballcatch_paper", "runs=2", "eval_episodes=1", "env.episode_length=120"]
    summed = initial.initial_evaluation(tiny)
    mean = initial.initial_evaluation([*tiny, "estimator.episode_return=mean"])
    assert summed["explorer"] == "sde" and summed["estimator"] == "reinforce"
    assert summed["initial_eval_return"] == pytest.approx(mean["initial_eval_return"], rel=1e-5)
    assert all(-3.0 <= r <= -0.5 for r in summed["initial_eval_return"])


def test_summed_returns_are_counted_as_mean_rewards(tmp_path):
    """The authors' learner regresses on summed rewards; the paper's levels are mean rewards."""
    for explorer, curves in CURVES.items():
        _write_job(tmp_path / "mean" / explorer, explorer, 0, curves)
        _write_job(tmp_path / "sum" / explorer, explorer, 0, curves, summed_over=500)
    fig5.main([str(tmp_path / "mean"), "--out", str(tmp_path / "a")])
    fig5.main([str(tmp_path / "sum"), "--out", str(tmp_path / "b")])
    a, b = (json.loads((tmp_path / d / "fig5.json").read_text()) for d in ("a", "b"))
    assert a == b and a["explorers"]["sde"]["best"]["-1.0"] == 1


def test_shards_merge_to_the_single_process_result(tmp_path):
    for explorer, curves in CURVES.items():
        _write_job(tmp_path / "whole" / explorer, explorer, 0, curves)
        _write_job(tmp_path / "shard_a" / explorer, explorer, 0, curves[:2])
        _write_job(tmp_path / "shard_b" / explorer, explorer, 2, curves[2:])
    fig5.main([str(tmp_path / "whole"), "--out", str(tmp_path / "one")])
    fig5.main([str(tmp_path / "shard_a"), str(tmp_path / "shard_b"), "--out", str(tmp_path / "two")])
    assert (tmp_path / "one" / "fig5.json").read_text() == (tmp_path / "two" / "fig5.json").read_text()


def test_conflicting_copies_of_a_run_are_refused(tmp_path):
    _write_job(tmp_path / "a", "sde", 0, CURVES["sde"][:1])
    _write_job(tmp_path / "b", "sde", 0, CURVES["sde"][1:2])
    with pytest.raises(ValueError, match="appears twice"):
        fig5.load_runs([tmp_path], "reinforce")


def test_no_runs_of_the_estimator_is_refused_in_one_line(tmp_path, capsys):
    assert fig5.main([str(tmp_path), "--out", str(tmp_path / "out"), "--estimator", "enac"]) == 2
    assert capsys.readouterr().err == f"error: no enac runs under {[str(tmp_path)]}\n"


@pytest.mark.e2e
def test_the_command_refuses_conflicting_copies_in_one_line_without_a_traceback(tmp_path):
    _write_job(tmp_path / "a", "sde", 0, CURVES["sde"][:1])
    _write_job(tmp_path / "b", "sde", 0, CURVES["sde"][1:2])
    command = [sys.executable, "-m", "analysis.paper.fig5", "--out", str(tmp_path / "out"), str(tmp_path)]
    result = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr[-2000:]
    assert result.stderr == (f"error: run 0 of sde appears twice with different results (second copy in "
                             f"{tmp_path / 'b'})\n"), result.stderr[-2000:]
    assert not (tmp_path / "out").exists()


@pytest.mark.e2e
def test_joblib_shards_of_a_ballcatch_sweep_give_the_same_table(tmp_path):
    """Real (short) ball-catching jobs: two shards over Hydra's joblib launcher and one process
    training both runs give the same fig5.json; the video script films the best run."""
    tiny = ["+experiment=ballcatch_paper", "updates=2", "episode_queue=2", "eval_period=1", "eval_episodes=1",
            "env.episode_length=40", "logger=none"]
    single = run_cli(*tiny, "runs=2", run_dir=tmp_path / "one", timeout=600)
    sharded = run_cli(*tiny, "runs=1", "first_run=0,1", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2",
                     run_dir=tmp_path / "shards", multirun=True, timeout=600)
    for result in (single, sharded):
        assert result.returncode == 0, result.stderr[-2000:]
    assert fig5.main([str(tmp_path / "one"), "--out", str(tmp_path / "fig_one")]) == 0
    assert fig5.main([str(tmp_path / "shards"), "--out", str(tmp_path / "fig_shards")]) == 0
    one = json.loads((tmp_path / "fig_one" / "fig5.json").read_text())
    assert one == json.loads((tmp_path / "fig_shards" / "fig5.json").read_text())
    assert one["explorers"]["sde"]["runs"] == 2

    video = subprocess.run([sys.executable, "-m", "analysis.paper.ballcatch_video", str(tmp_path / "shards"),
                            "--out", str(tmp_path / "best.gif")], cwd=REPO, capture_output=True, text=True,
                           timeout=600)
    assert video.returncode == 0, video.stderr[-2000:]
    line = json.loads(video.stdout.strip().splitlines()[-1])
    summary = json.loads((tmp_path / "one" / "summary.json").read_text())
    finals = summary["final_eval_return"]
    assert line["run"] == max(range(2), key=finals.__getitem__) and line["model"] == "pybrain"
    assert line["final_eval_return"] == pytest.approx(max(finals) / 40, abs=1e-4)  # summed over 40 steps
    assert -3.0 <= line["filmed_return"] <= -0.5 and (tmp_path / "best.gif").stat().st_size > 0


def test_video_picks_the_best_or_the_median_run():
    from analysis.paper import ballcatch_video as video
    runs = [video.Run(index, final, None, "pybrain") for index, final in enumerate([-2.0, -1.0, -3.0, -1.5, -2.5])]
    assert video.pick(runs, "best").index == 1
    assert video.pick(runs, "median").index == 0  # -2.0, the middle of five
    assert video.pick(runs + [video.Run(5, -1.0, None, "pybrain")], "best").index == 1  # ties: the lower index


def _write_final_policy(directory: Path, explorer: str, first_run: int, returns: list[float],
                        episodes: int = 20, seed: int = 7) -> None:
    """``final_policy.json`` as ``analysis/paper/ballcatch_final.py`` writes it into a job directory."""
    (directory / "final_policy.json").write_text(json.dumps(
        {"explorer": explorer, "estimator": "reinforce", "first_run": first_run, "episodes": episodes, "seed": seed,
         "final_policy_return": returns}))


def test_final_policies_on_more_episodes_are_counted_beside_the_trainers_evaluation(tmp_path):
    for explorer, curves in CURVES.items():
        _write_job(tmp_path / explorer, explorer, 0, curves)
    _write_final_policy(tmp_path / "sde", "sde", 0, [-1.08, -1.0, -1.7, -1.12])
    _write_final_policy(tmp_path / "rex", "rex", 0, [-1.95, -1.5, -3.0, -1.2])
    assert fig5.main([str(tmp_path), "--out", str(tmp_path / "out"), "--estimator", "reinforce"]) == 0
    result = json.loads((tmp_path / "out" / "fig5.json").read_text())
    sde, rex = result["explorers"]["sde"], result["explorers"]["rex"]
    assert result["final_policy"] == {"episodes": 20, "seed": 7}
    assert sde["final"]["-1.1"] == 1 and sde["final_policy"]["-1.1"] == 2 and sde["final_policy"]["-1.0"] == 1
    assert rex["final_policy"] == {"-2.0": 3, "-1.5": 2, "-1.1": 0, "-1.0": 0}
    assert result["sde_minus_rex"]["final_policy"]["-1.1"]["estimate"] == pytest.approx(0.5)
    table = (tmp_path / "out" / "fig5.md").read_text()
    assert "evaluated on 20 episodes (seed 7" in table
    assert "| SDE | 4 | 100 % [51, 100] | 75 % [30, 95] | 50 % [15, 85] | 25 % [5, 70] |" in table


def test_final_policies_of_some_runs_only_or_of_two_evaluations_or_damaged_are_refused(tmp_path, capsys):
    def refusal() -> str:
        assert fig5.main([str(tmp_path), "--out", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1, err
        return err

    _write_job(tmp_path / "sde", "sde", 0, CURVES["sde"])
    _write_final_policy(tmp_path / "sde", "sde", 0, [-1.0, -1.0])
    assert "sde: 2 runs (first 2) have no final_policy.json entry" in refusal()
    _write_job(tmp_path / "more", "sde", 2, CURVES["sde"][2:])
    _write_final_policy(tmp_path / "more", "sde", 2, [-1.0, -1.0], episodes=10)
    assert "final_policy.json files of different evaluations" in refusal()
    (tmp_path / "more" / "final_policy.json").write_text('{"explorer": "sde", ')
    assert refusal().startswith(f"error: {tmp_path / 'more' / 'final_policy.json'} cannot be read as JSON")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("experiment", [["+experiment=ballcatch_reinforce", "episode_queue=2"],  # σ̂ learned
                                        ["+experiment=ballcatch_enac"]])  # σ̂ fixed: not a parameter
@pytest.mark.e2e
def test_final_policy_evaluation_repeats_the_trainers_final_evaluation(tmp_path, experiment):
    """Given the job's own seed and episode count, the evaluation of the loaded final controllers
    is the trainer's final evaluation, to the bit, however the runs are split into chunks; on
    another seed the balls differ; a job the config tree no longer rebuilds is refused."""
    from analysis.paper import ballcatch_final as final
    from sde_torchrl.trainers.summary import mean_reward_factor
    job = [*experiment, "runs=3", "updates=2", "eval_period=2", "env.episode_length=60", "logger=none"]
    assert run_cli(*job, run_dir=tmp_path / "job", timeout=600).returncode == 0
    summary = json.loads((tmp_path / "job" / "summary.json").read_text())
    assert final.main(["--episodes", "3", "--seed", "0", "--chunk", "2", str(tmp_path)]) == 0
    found = json.loads((tmp_path / "job" / "final_policy.json").read_text())
    factor = mean_reward_factor(summary)  # 1 for mean returns, 1/T for ENAC's summed ones
    assert found["final_policy_return"] == [factor * r for r in summary["final_eval_return"]]
    assert (found["explorer"], found["first_run"]) == ("sde", 0)
    with pytest.raises(SystemExit):  # the file holds another evaluation
        final.main(["--episodes", "3", "--seed", "7", str(tmp_path)])
    assert final.main(["--episodes", "3", "--seed", "7", "--chunk", "3", "--force", str(tmp_path)]) == 0
    other = json.loads((tmp_path / "job" / "final_policy.json").read_text())["final_policy_return"]
    assert other != [factor * r for r in summary["final_eval_return"]]
    overrides = tmp_path / "job" / ".hydra" / "overrides.yaml"
    overrides.write_text(overrides.read_text() + "- env.jitter=0.1\n")
    with pytest.raises(SystemExit, match="env.jitter: 0.05 -> 0.1"):
        final.main(["--episodes", "3", "--seed", "7", "--force", str(tmp_path)])
