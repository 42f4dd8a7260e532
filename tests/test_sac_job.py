"""SAC from the command line (``algorithm=sac``): the zoo's experiments compose, a short job writes
its run directory, a SIGTERM then the same command equals an uninterrupted job (replay buffer
included), the noise is redrawn as SB3's ``sde_sample_freq`` says, bad values are one line naming
the key."""

from __future__ import annotations

import math
import signal
from concurrent.futures import ThreadPoolExecutor

import pytest
import torch
from _helpers import compose_config, own_stderr_lines, read_rows, run_cli, summary_without_wall
from test_checkpoint import rows_in, start_and_signal

from sde_torchrl.config.errors import describe_error
from sde_torchrl.config.schemas.algorithms import SACConf
from sde_torchrl.config.schemas.policy import ExplorerConf, GaussianExplorerConf
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.jobs.checkpoint import load_checkpoint
from sde_torchrl.jobs.run_dir import read_finished_run

#: A SAC job of a few seconds on Pendulum-v1: rounds of 8 steps and 8 gradient steps, 2 rounds an
#: update, 32 steps of random actions first.
TINY = ("algorithm=sac", "env=gym", "env.episode_length=50", "algorithm.train_freq=8", "algorithm.gradient_steps=8",
        "algorithm.batch_size=32", "algorithm.learning_starts=32", "algorithm.rounds_per_update=2",
        "algorithm.buffer_size=200", "eval_period=10", "eval_episodes=2", "actor.hidden=[16,16]", "lr=1e-3")
EXPERIMENTS = [f"sac_{env}_bullet" for env in ("halfcheetah", "ant", "hopper", "walker2d")]


@pytest.mark.parametrize("explorer", [None, "gaussian"])
@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_sac_experiment_composes_with_the_zoo_settings(experiment, explorer):
    """hyperparams/sac.yml's pybullet-defaults; Hopper's and Walker2D's rate decays (lin_7.3e-4)."""
    conf = validate(compose_config(f"+experiment={experiment}", *([f"explorer={explorer}"] if explorer else [])))
    alg, env = conf.algorithm, experiment.split("_")[1]
    assert isinstance(alg, SACConf) and conf.estimator is None and conf.runs == 1
    assert (alg.buffer_size, alg.batch_size, alg.learning_starts, alg.train_freq, alg.gradient_steps, alg.gamma,
            alg.tau, alg.ent_coef) == (300_000, 256, 10_000, 8, 8, 0.98, 0.02, "auto")
    assert conf.updates * alg.rounds_per_update * alg.train_freq == 1_000_000
    assert conf.lr == 7.3e-4 and conf.optimizer.lr_schedule == ("linear" if env in ("hopper", "walker2d") else
                                                                "constant")
    assert (conf.actor.hidden, conf.actor.activation, conf.actor.init) == ([400, 300], "relu", None)
    assert conf.env.id.lower() == f"pybullet_envs_gymnasium:{env}bulletenv-v0" and conf.env.episode_length == 1000
    assert isinstance(conf.explorer, GaussianExplorerConf if explorer else ExplorerConf) and conf.explorer.squash
    if not explorer:  # use_sde, sde_sample_freq=-1, log_std_init=-3, use_expln=False
        assert (conf.explorer.schedule, conf.explorer.sigma_transform, conf.explorer.init_param) == (
            "rollout", "exp", -3.0)


def test_the_mountaincar_experiment_composes_with_the_zoo_settings():
    """hyperparams/sac.yml's MountainCarContinuous-v0 entry, 50,016 env steps as SB3 runs them."""
    conf = validate(compose_config("+experiment=sac_mountaincar"))
    alg = conf.algorithm
    assert (alg.buffer_size, alg.batch_size, alg.learning_starts, alg.train_freq, alg.gradient_steps, alg.gamma,
            alg.tau, alg.ent_coef, alg.compile) == (50_000, 512, 0, 32, 32, 0.9999, 0.01, 0.1, True)
    assert conf.updates * alg.rounds_per_update * alg.train_freq == 50_016
    assert (conf.lr, conf.actor.hidden, conf.explorer.init_param, conf.env.id) == (
        3e-4, [64, 64], -3.67, "MountainCarContinuous-v0")


@pytest.mark.e2e  # torch.compile (inductor)
@pytest.mark.parametrize("ent_coef", [0.1, "auto"])
def test_the_compiled_gradient_step_gives_the_eager_ones_numbers_to_rounding(ent_coef):
    """Two trainers in the same state, one eager and one compiled (``algorithm.compile``): a few
    gradient steps on the same minibatches move every parameter alike; the fresh loss noise is
    drawn outside the compiled graphs, so both draw the same."""
    trainers = [_trainer("explorer=gsde_freq4", f"algorithm.ent_coef={ent_coef}", f"algorithm.compile={c}")
                for c in ("false", "true")]
    compiled = trainers[1].update_step
    assert hasattr(compiled.critic_objective, "_torchdynamo_orig_callable")
    assert not hasattr(trainers[0].update_step.critic_objective, "_torchdynamo_orig_callable")
    assert all(opt.defaults["fused"] for opt in compiled.optimizers.values())
    for trainer in trainers:
        trainer.update(0)  # the random warm-up fills the buffer; both are in the same state
    before = {k: v.clone() for k, v in trainers[0].update_step.loss.state_dict().items()}
    batches = [trainers[0].buffer.sample() for _ in range(3)]
    states = []
    for trainer in trainers:
        torch.manual_seed(1)
        for batch in batches:
            assert torch.isfinite(trainer.update_step(batch.clone()))
        states.append(trainer.update_step.loss.state_dict())
    assert any(not torch.equal(states[0][key], value) for key, value in before.items())  # the steps moved them
    for key, eager in states[0].items():
        torch.testing.assert_close(states[1][key], eager, rtol=1e-4, atol=1e-5, msg=key)
    for trainer in trainers:
        trainer.close()


def _trainer(*overrides: str):
    from sde_torchrl.config.build_sac import build_sac_trainer

    return build_sac_trainer(validate(compose_config(*TINY, "updates=4", "logger=none", *overrides)))


@pytest.mark.parametrize(("explorer", "redraws"), [("gsde", [0]), ("gsde_freq4", [0, 4])])
def test_the_noise_is_redrawn_as_sb3s_sde_sample_freq_counts(explorer, redraws):
    """-1: once per round of train_freq steps, through episode ends; 4: every 4 steps of the round."""
    trainer = _trainer(f"explorer={explorer}", "env.episode_length=5")
    trainer.collector.keep = None  # the job's rollouts keep no noise; this test looks at the one each action used
    previous = None
    try:
        for _ in range(3):
            noise = trainer.collector.rollout()["sde_noise"][0]  # [train_freq, A, S], the one each action used
            changed = [t for t in range(8) if t == 0 or not torch.equal(noise[t], noise[t - 1])]
            assert changed == redraws, changed
            assert previous is None or not torch.equal(noise[0], previous)  # each round starts with a fresh ξ
            previous = noise[-1]
    finally:
        trainer.close()


def test_warm_up_then_gradient_steps_and_a_buffer_without_noise():
    """Uniform actions until learning_starts (no gradient step after those rounds), then 8 steps a round."""
    trainer = _trainer("explorer=gsde")
    try:
        norms = [float(trainer.update(k)["grad_norm"][0]) for k in range(3)]  # 16 steps an update
        assert norms[:2] == [0.0, 0.0] and norms[2] > 0  # SB3: trains once more than 32 steps are collected
        assert len(trainer.buffer) == 48 and "sde_noise" not in trainer.buffer[:2].keys()
        assert trainer.collector.policy is trainer.policy
    finally:
        trainer.close()


def test_the_learning_rate_decays_per_round_as_sb3s_linear_schedule():
    """lin_7.3e-4: the round of gradient steps after r + 1 rounds of R runs at 7.3e-4 · (1 - (r + 1) / R)."""
    trainer = _trainer("optimizer.lr_schedule=linear", "lr=7.3e-4")
    try:
        for k in range(3):
            trainer.update(k)
        rounds = 4 * 2
        for optimizer in trainer.update_step.optimizers.values():  # critic, actor, entropy coefficient
            assert optimizer.param_groups[0]["lr"] == pytest.approx(7.3e-4 * (1 - 6 / rounds))
    finally:
        trainer.close()


@pytest.mark.e2e
def test_a_short_job_writes_its_run_directory(tmp_path):
    result = run_cli(*TINY, "updates=4", "explorer=gsde", run_dir=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    rows = read_rows(tmp_path)
    assert [int(row["update"]) for row in rows] == list(range(4))
    assert [float(row["grad_norm"]) > 0 for row in rows] == [False, False, True, True]  # after 32 steps
    assert [int(row["episodes"]) for row in rows] == [0, 0, 0, 1]  # 16 steps an update, 50 an episode
    job = read_finished_run(tmp_path)
    assert job.summary["algorithm"] == "sac" and job.summary["env_steps"] == 4 * 16
    assert job.summary["final_eval_return"] == [float(rows[-1]["eval_return"])]


@pytest.mark.parametrize("explorer", ["gsde_freq4", "gaussian", "gsde_freq4 algorithm.compile=true"])
@pytest.mark.e2e
def test_sigterm_then_the_same_command_equals_an_uninterrupted_job(tmp_path, explorer):
    """The checkpoint holds the replay buffer, the optimisers and the env mid-episode."""
    updates = 20
    explorer, *more = explorer.split()
    cli = (*TINY, f"updates={updates}", "checkpoint_period=0", f"explorer={explorer}", *more)
    with ThreadPoolExecutor(max_workers=1) as pool:
        reference = pool.submit(run_cli, *cli, run_dir=tmp_path / "ref")
        run_dir = tmp_path / "terminated"
        stopped = start_and_signal(run_dir, signal.SIGTERM, after_rows=6, cli=cli)
        assert stopped.returncode == 143, stopped.stderr[-2000:]
        lines = own_stderr_lines(stopped.stderr)
        assert len(lines) == 1 and lines[0].startswith("interrupted by SIGTERM: checkpoint after update "), lines
        saved = load_checkpoint(run_dir / "checkpoint.pt")
        done = saved["updates"]
        assert rows_in(run_dir / "metrics.csv") == done < updates
        assert saved["loop"]["rollout"]["buffer"]["_storage"]["_len"] == done * 16 < 200  # not yet wrapped
        finished = run_cli(*cli, run_dir=run_dir)
        assert finished.returncode == 0, finished.stderr[-2000:]
        assert f"resuming {run_dir} after update {done} of {updates}" in finished.stdout
        assert reference.result().returncode == 0
    assert (run_dir / "metrics.csv").read_bytes() == (tmp_path / "ref" / "metrics.csv").read_bytes()
    assert summary_without_wall(run_dir) == summary_without_wall(tmp_path / "ref")


def test_one_update_of_a_bullet_experiment_with_tiny_sizes():
    """The experiment as it builds: the PyBullet env through its module id, SB3's Adam rate (its
    compiled losses: the end-to-end tests)."""
    pytest.importorskip("pybullet_envs_gymnasium")
    from sde_torchrl.config.build_sac import build_sac_trainer

    conf = validate(compose_config("+experiment=sac_halfcheetah_bullet", "algorithm.compile=false",
                                   "algorithm.learning_starts=16",
                                   "algorithm.batch_size=8", "algorithm.rounds_per_update=3", "actor.hidden=[8]",
                                   "updates=2", "eval_episodes=1", "env.episode_length=20", "logger=none"))
    trainer = build_sac_trainer(conf)
    try:
        stats = trainer.update(0)
        assert float(stats["grad_norm"][0]) > 0
        assert float(stats["exploration"][0, 0]) == pytest.approx(float(torch.tensor(-3.0).exp()), rel=0.05)
        assert trainer.buffer[:1]["observation"].shape == (1, 26) and trainer.evaluate().shape == (1,)
    finally:
        trainer.close()


BAD = [
    (("algorithm.bogus=1",), "algorithm.bogus: unknown key"),
    (("algorithm.n_steps=8",), "algorithm.n_steps: unknown key"),  # PPO's, not SAC's
    (("runs=2",), "runs=2: 1 with algorithm=sac"),
    (("algorithm.learning_starts=20",), "algorithm.learning_starts=20: a multiple of algorithm.train_freq (8)"),
    (("algorithm.ent_coef=-0.1",), "algorithm.ent_coef=-0.1: auto or a finite number > 0"),
    (("algorithm.ent_coef=manual",), "algorithm.ent_coef=manual: auto or a finite number > 0"),
    (("algorithm.tau=2",), "algorithm.tau=2"),
    (("algorithm.gradient_steps=0",), "algorithm.gradient_steps=0: a positive integer"),
    (("explorer=gsde", "explorer.squash=false"), "explorer.squash=false: true with algorithm=sac"),
    (("explorer=gaussian", "explorer.learn_sigma=false"), "explorer.learn_sigma=false: true with algorithm=sac"),
    (("explorer=gsde", "explorer.rollout_steps=7"), "explorer.rollout_steps=7: null or algorithm.train_freq (8)"),
    (("algorithm.buffer_size=10000000000", "updates=1000000000", "max_memory_gb=4"),
     "algorithm.buffer_size=10000000000: the job would hold about"),
]


@pytest.mark.parametrize(("overrides", "expected"), BAD)
def test_bad_values_are_one_line_naming_the_key(overrides, expected):
    with pytest.raises(Exception) as info:
        validate(compose_config(*TINY, *overrides))
    assert describe_error(info.value).startswith(expected), describe_error(info.value)


def test_an_unknown_option_on_the_command_line_exits_2_in_one_line(tmp_path):
    result = run_cli(*TINY, "algorithm.n_epochs=3", run_dir=tmp_path)
    lines = own_stderr_lines(result.stderr)
    assert result.returncode == 2 and len(lines) == 1, (result.returncode, result.stderr[-2000:])
    assert lines[0].startswith("error: algorithm.n_epochs"), lines
    assert not (tmp_path / "metrics.csv").exists()


def test_launchers_request_the_estimated_memory_and_time():
    """The zoo's job: 11 PyBullet worlds and a buffer of 300,000 transitions; 1M steps and 51
    evaluations of 10 episodes at the assumed 20 env steps/s, with the launcher's margin."""
    from sde_torchrl.jobs.resources import estimate_memory, launcher_request

    conf = validate(compose_config("+experiment=sac_halfcheetah_bullet"))
    assert 0.5 < estimate_memory(conf).total_gb < 2.0
    assert launcher_request(conf)["timeout_min"] == math.ceil(1.3 * (1_000_000 + 51 * 10 * 1000) / 20 / 60)
