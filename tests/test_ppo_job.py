"""PPO and A2C from the command line (``algorithm=ppo|a2c``): the experiments compose, a short job
writes its run directory, a SIGTERM then the same command equals an uninterrupted job, bad values
are one line and exit 2 naming the key."""

from __future__ import annotations

import json
import signal
from concurrent.futures import ThreadPoolExecutor

import pytest
import torch
from _helpers import compose_config, own_stderr_lines, read_rows, run_cli, summary_without_wall
from tensordict import TensorDict
from test_checkpoint import rows_in, start_and_signal

from sde_torchrl.config.errors import describe_error
from sde_torchrl.config.schemas.algorithms import A2CConf, PPOConf
from sde_torchrl.config.schemas.optimizers import RMSpropOptimizerConf
from sde_torchrl.config.schemas.policy import ExplorerConf, GaussianExplorerConf
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.jobs.checkpoint import load_checkpoint
from sde_torchrl.jobs.run_dir import read_finished_run

#: A PPO job of a few seconds on Pendulum-v1: 2 envs × 32 steps per update.
TINY = ("algorithm=ppo", "env=gym", "env.episode_length=50", "algorithm.n_envs=2", "algorithm.n_steps=32",
        "algorithm.batch_size=16", "algorithm.n_epochs=2", "algorithm.normalize=true", "eval_period=7",
        "eval_episodes=2", "actor.hidden=[16,16]", "actor.activation=relu", "actor.init=null", "lr=1e-3")
#: An A2C job of a few seconds on Pendulum-v1: 2 envs × 8 steps per update, the time feature, a
#: linearly decaying rate, one noise matrix per rollout.
TINY_A2C = ("algorithm=a2c", "env=gym", "env.episode_length=50", "algorithm.n_envs=2", "algorithm.n_steps=8",
            "algorithm.normalize=true", "algorithm.time_feature=true", "optimizer.lr_schedule=linear", "eval_period=50",
            "eval_episodes=2", "actor.hidden=[16,16]", "actor.init=null", "lr=1e-3")


def test_the_halfcheetah_experiment_composes_with_the_zoo_settings():
    conf = validate(compose_config("+experiment=ppo_halfcheetah_bullet"))
    assert isinstance(conf.algorithm, PPOConf) and conf.estimator is None and conf.runs == 1
    alg = conf.algorithm
    assert (alg.n_envs, alg.n_steps, alg.batch_size, alg.n_epochs, alg.gamma, alg.gae_lambda, alg.clip_range,
            alg.ent_coef, alg.vf_coef, alg.max_grad_norm, alg.normalize) == (
        16, 512, 128, 20, 0.99, 0.9, 0.4, 0.0, 0.5, 0.5, True)
    assert (conf.lr, conf.optimizer.eps, conf.actor.hidden, conf.actor.activation, conf.actor.init) == (
        3e-5, 1e-5, [256, 256], "relu", None)
    assert conf.updates * alg.n_envs * alg.n_steps >= 2_000_000 > (conf.updates - 1) * alg.n_envs * alg.n_steps
    assert alg.compile and not PPOConf().compile  # the zoo's experiments compile; the group's default is eager
    sde = conf.explorer  # SB3's sde_sample_freq=4, counted over the rollout; log_std_init=-2, use_expln=False
    assert isinstance(sde, ExplorerConf)
    assert (sde.schedule, sde.every_n, sde.sigma_transform, sde.init_param, sde.sharing) == (
        "every_n_steps", 4, "exp", -2.0, "element")
    gaussian = validate(compose_config("+experiment=ppo_halfcheetah_bullet", "explorer=gaussian")).explorer
    assert isinstance(gaussian, GaussianExplorerConf) and gaussian.init_param == -2.0


def test_the_a2c_experiment_composes_with_the_zoo_settings():
    conf = validate(compose_config("+experiment=a2c_halfcheetah_bullet"))
    alg = conf.algorithm
    assert isinstance(alg, A2CConf) and conf.estimator is None
    assert (alg.n_envs, alg.n_steps, alg.gamma, alg.gae_lambda, alg.ent_coef, alg.vf_coef, alg.max_grad_norm,
            alg.normalize_advantage, alg.normalize, alg.time_feature) == (
        4, 8, 0.99, 0.9, 0.0, 0.4, 0.5, False, True, True)
    assert conf.updates * alg.n_envs * alg.n_steps == 2_000_000
    assert isinstance(conf.optimizer, RMSpropOptimizerConf)  # SB3's use_rms_prop, lin_0.00096
    assert (conf.lr, conf.optimizer.alpha, conf.optimizer.eps, conf.optimizer.lr_schedule) == (
        9.6e-4, 0.99, 1e-5, "linear")
    assert (conf.actor.hidden, conf.actor.activation, conf.actor.init) == ([64, 64], "tanh", None)
    sde = conf.explorer  # SB3's default sde_sample_freq=-1: one matrix per rollout
    assert (sde.schedule, sde.every_n, sde.sigma_transform, sde.init_param) == ("rollout", None, "exp", -2.0)
    assert isinstance(validate(compose_config("+experiment=a2c_halfcheetah_bullet", "explorer=gaussian")).explorer,
                      GaussianExplorerConf)


EXPERIMENTS = [f"{algorithm}_{env}_bullet" for algorithm in ("ppo", "a2c")
               for env in ("halfcheetah", "ant", "hopper", "walker2d")]


@pytest.mark.parametrize("explorer", [None, "gaussian"])
@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_bullet_experiment_composes(experiment, explorer):
    """The zoo's entries: Ant's log σ₀ is -1, Hopper's and Walker2D's PPO clip range decays
    (lin_0.4); A2C has one entry for the four envs."""
    conf = validate(compose_config(f"+experiment={experiment}", *([f"explorer={explorer}"] if explorer else [])))
    algorithm, env, _ = experiment.split("_")
    assert type(conf.algorithm) is {"ppo": PPOConf, "a2c": A2CConf}[algorithm]
    assert conf.env.id.lower().startswith(f"pybullet_envs_gymnasium:{env}bulletenv")
    assert conf.env.episode_length == 1000 and conf.algorithm.normalize
    assert isinstance(conf.explorer, GaussianExplorerConf if explorer else ExplorerConf)
    assert conf.explorer.init_param == (-1.0 if experiment == "ppo_ant_bullet" else -2.0)
    if algorithm == "ppo":
        assert conf.algorithm.clip_range_schedule == ("linear" if env in ("hopper", "walker2d") else "constant")


def test_one_update_of_a_bullet_experiment_with_tiny_sizes():
    """The experiment as it builds: the PyBullet env through its module id, the linear clip
    range (0.4 at the first update, 0.2 halfway). Eager: the compiled objective has its own
    end-to-end test, and compiling it here would cost this fast-loop test three quarters of its time."""
    pytest.importorskip("pybullet_envs_gymnasium")
    from sde_torchrl.config.build_onpolicy import build_onpolicy_trainer

    conf = validate(compose_config("+experiment=ppo_hopper_bullet", "algorithm.n_envs=2", "algorithm.n_steps=16",
                                   "algorithm.batch_size=16", "algorithm.n_epochs=1", "actor.hidden=[8]",
                                   "updates=2", "eval_episodes=1", "logger=none", "algorithm.compile=false"))
    trainer = build_onpolicy_trainer(conf)
    try:
        assert trainer.update(0)["return_mean"].isfinite().all()
        assert float(trainer.update_step.loss.clip_epsilon) == pytest.approx(0.4)
        trainer.update(1)
        assert float(trainer.update_step.loss.clip_epsilon) == pytest.approx(0.2)
        assert trainer.evaluate().shape == (1,)
    finally:
        trainer.close()


@pytest.mark.parametrize("algorithm", ["ppo", "a2c"])
def test_rollouts_keep_what_the_update_reads_and_update_alike(algorithm):
    """The collector keeps no SDE matrix per step (ξ, σ̂), and the update from that lean rollout
    equals the update from one keeping every key, bit for bit."""
    from sde_torchrl.config.build_onpolicy import build_onpolicy_trainer

    results = []
    for keep_all in (False, True):  # one after the other: both draw from torch's global generator
        trainer = build_onpolicy_trainer(validate(compose_config(*(TINY if algorithm == "ppo" else TINY_A2C),
                                                                 "logger=none")))
        if keep_all:
            trainer.collector.keep = None
        try:
            row = trainer.update(0)
            keys = set(trainer.collector.rollout().keys(True, True))
            results.append((row["grad_norm"], trainer.modules.state_dict(), keys))
        finally:
            trainer.close()
    (lean_norm, lean_state, lean_keys), (full_norm, full_state, full_keys) = results
    assert not {"sde_noise", "sde_sigma_hat", ("next", "sde_noise")} & lean_keys
    assert {"sde_noise", "sde_sigma_hat", ("next", "sde_noise")} <= full_keys
    assert torch.equal(lean_norm, full_norm)
    for name, value in lean_state.items():
        assert torch.equal(value, full_state[name]), name


@pytest.mark.e2e
def test_a_short_job_writes_its_run_directory(tmp_path):
    result = run_cli(*TINY, "updates=5", "explorer=gsde", run_dir=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    for name in ("metrics.csv", "summary.json", "checkpoint.pt", "job_config.json", ".hydra/config.yaml"):
        assert (tmp_path / name).exists(), name
    rows = read_rows(tmp_path)
    assert [int(row["update"]) for row in rows] == list(range(5))
    assert rows[-1]["eval_return"] and not rows[0]["eval_return"]
    assert [int(row["episodes"]) for row in rows] == [0, 2, 2, 4, 6]  # 2 envs, 32 steps an update, 50 an episode
    job = read_finished_run(tmp_path)  # the one reader accepts it: its files agree
    assert job.summary["algorithm"] == "ppo" and job.summary["explorer"] == "gsde"
    assert job.summary["env_steps"] == 5 * 64 and job.summary["episodes"] == 6
    assert job.summary["final_eval_return"] == [float(rows[-1]["eval_return"])]
    again = run_cli(*TINY, "updates=5", "explorer=gsde", run_dir=tmp_path)  # a finished job is final
    assert again.returncode == 0 and "holds a finished job" in again.stdout


@pytest.mark.parametrize(("job", "explorer", "updates"), [
    (TINY, "gsde_freq4", 40), (TINY, "gaussian", 40), (TINY_A2C, "gsde", 150),
    ((*TINY, "algorithm.compile=true"), "gsde_freq4", 40)])
@pytest.mark.e2e
def test_sigterm_then_the_same_command_equals_an_uninterrupted_job(tmp_path, job, explorer, updates):
    """The envs are mid-episode at the checkpoint: the resumed job replays their episodes."""
    cli = (*job, f"updates={updates}", "checkpoint_period=0", f"explorer={explorer}")
    with ThreadPoolExecutor(max_workers=1) as pool:
        reference = pool.submit(run_cli, *cli, run_dir=tmp_path / "ref")
        run_dir = tmp_path / "terminated"
        stopped = start_and_signal(run_dir, signal.SIGTERM, after_rows=updates // 5, cli=cli)
        assert stopped.returncode == 143, stopped.stderr[-2000:]
        lines = own_stderr_lines(stopped.stderr)
        assert len(lines) == 1 and lines[0].startswith("interrupted by SIGTERM: checkpoint after update "), lines
        done = load_checkpoint(run_dir / "checkpoint.pt")["updates"]
        assert rows_in(run_dir / "metrics.csv") == done < updates
        finished = run_cli(*cli, run_dir=run_dir)
        assert finished.returncode == 0, finished.stderr[-2000:]
        assert f"resuming {run_dir} after update {done} of {updates}" in finished.stdout
        assert reference.result().returncode == 0
    assert (run_dir / "metrics.csv").read_bytes() == (tmp_path / "ref" / "metrics.csv").read_bytes()
    assert summary_without_wall(run_dir) == summary_without_wall(tmp_path / "ref")
    scalars = run_dir / "sde_torchrl" / "scalars" / "return_mean.csv"  # TorchRL's CSV logger, cut back and continued
    assert scalars.read_bytes() == (tmp_path / "ref" / scalars.relative_to(run_dir)).read_bytes()


@pytest.mark.e2e
def test_a_kill_between_checkpoints_then_the_same_command_redoes_the_lost_updates(tmp_path):
    """SIGKILL: the rows after the last periodic checkpoint are cut back and done again, the same."""
    cli = (*TINY, "updates=40", "checkpoint_period=5", "explorer=gsde_freq4")
    with ThreadPoolExecutor(max_workers=1) as pool:
        reference = pool.submit(run_cli, *cli, run_dir=tmp_path / "ref")
        run_dir = tmp_path / "killed"
        killed = start_and_signal(run_dir, signal.SIGKILL, after_rows=17, cli=cli)
        assert killed.returncode == -signal.SIGKILL
        done = load_checkpoint(run_dir / "checkpoint.pt")["updates"]
        assert done % 5 == 0 and rows_in(run_dir / "metrics.csv") >= done
        finished = run_cli(*cli, run_dir=run_dir)
        assert finished.returncode == 0, finished.stderr[-2000:]
        assert reference.result().returncode == 0
    assert (run_dir / "metrics.csv").read_bytes() == (tmp_path / "ref" / "metrics.csv").read_bytes()
    assert summary_without_wall(run_dir) == summary_without_wall(tmp_path / "ref")


BAD = [
    (("runs=2",), "runs=2: 1 with algorithm=ppo"),
    (("algorithm.batch_size=100",), "algorithm.batch_size=100: at most algorithm.n_envs × algorithm.n_steps = 64"),
    (("algorithm.gamma=1.5",), "algorithm.gamma=1.5:"),
    (("algorithm.n_epochs=0",), "algorithm.n_epochs=0: a positive integer"),
    (("algorithm.clip_range=0",), "algorithm.clip_range=0.0: a finite number > 0"),
    (("estimator=reinforce",), "estimator=ReinforceEstimator: null with algorithm=ppo"),
    (("env=minimize",), "env=make_minimize_env: env=gym with algorithm=ppo"),
    (("actor.bias=false",), "actor.bias=false: actor=mlp with bias with algorithm=ppo"),
    (("explorer=pgpe",), "explorer=pgpe: an SDE explorer"),
    (("optimizer.sigma_lr_factor=10",), "optimizer.sigma_lr_factor=10.0: 1 with algorithm=ppo"),
    (("explorer=gsde", "explorer.rollout_steps=7"), "explorer.rollout_steps=7: null or algorithm.n_steps (32)"),
    (("env.normalize_obs=stats",), "env.normalize_obs=stats: null (false) with algorithm=ppo"),
    (("algorithm.bogus=1",), "algorithm.bogus: unknown key"),
    (("algorithm.clip_range_schedule=cosine",), "algorithm.clip_range_schedule=cosine: one of constant, linear"),
    (("algorithm.n_steps=1000000", "max_memory_gb=4"), "algorithm.n_steps=1000000: the job would hold about"),
]


@pytest.mark.parametrize(("overrides", "expected"), BAD)
def test_bad_values_are_one_line_naming_the_key(overrides, expected):
    with pytest.raises(Exception) as info:
        validate(compose_config(*TINY, *overrides))
    assert describe_error(info.value).startswith(expected), describe_error(info.value)


BAD_A2C = [
    (("algorithm.batch_size=4",), "algorithm.batch_size: unknown key"),  # PPO's, not A2C's
    (("runs=3",), "runs=3: 1 with algorithm=a2c"),
    (("algorithm.gae_lambda=-0.1",), "algorithm.gae_lambda=-0.1:"),
    (("optimizer.alpha=1.5",), "optimizer.alpha=1.5: a number in [0, 1)"),
]


@pytest.mark.parametrize(("overrides", "expected"), BAD_A2C)
def test_bad_a2c_values_are_one_line_naming_the_key(overrides, expected):
    with pytest.raises(Exception) as info:
        validate(compose_config(*TINY_A2C, *overrides))
    assert describe_error(info.value).startswith(expected), describe_error(info.value)


def test_the_gaussian_baseline_is_refused_for_the_episodic_estimators():
    with pytest.raises(Exception) as info:
        validate(compose_config("+experiment=pendulum", "explorer=gaussian"))
    assert describe_error(info.value).startswith("explorer=gaussian: an SDE or PGPE explorer for the episodic")


def test_bad_values_on_the_command_line_exit_2_in_one_line(tmp_path):
    cases = {"runs": ("runs=2",), "batch": ("algorithm.batch_size=100",)}
    with ThreadPoolExecutor(max_workers=2) as pool:
        futures = {name: pool.submit(run_cli, *TINY, *overrides, run_dir=tmp_path / name)
                   for name, overrides in cases.items()}
        results = {name: future.result() for name, future in futures.items()}
    for name, result in results.items():
        lines = own_stderr_lines(result.stderr)
        assert result.returncode == 2 and len(lines) == 1, (name, result.returncode, result.stderr[-2000:])
        assert lines[0].startswith(f"error: {cases[name][0].split('=')[0]}="), lines
        assert not (tmp_path / name / "metrics.csv").exists()


def test_a_bullet_env_replays_to_the_same_state_bit_for_bit():
    """What resuming a job on the PyBullet envs rests on: a fresh env reset with an episode's seed
    and stepped with its actions arrives where the first one was, through earlier episodes."""
    pytest.importorskip("pybullet_envs_gymnasium")
    from sde_torchrl.envs.vector import GymVectorEnv, ReplayMismatchError

    env_id = "pybullet_envs_gymnasium:HalfCheetahBulletEnv-v0"
    env = GymVectorEnv(env_id, n_envs=2, episode_length=15)
    torch.manual_seed(0)
    env.rollout(40, lambda td: td.set("action", torch.rand(2, 6) * 2 - 1), break_when_any_done=False)
    state = env.replay_state()
    assert [len(actions) for actions in state["actions"]] == [10, 10]  # the third episode of each env
    fresh = GymVectorEnv(env_id, n_envs=2, episode_length=15)
    fresh.restore_replay(state)
    step = TensorDict({"action": torch.rand(2, 6)}, [2])
    assert torch.equal(env.step(step.clone())["next", "observation"], fresh.step(step.clone())["next", "observation"])
    state["observation"][1, 0] += 1.0
    with pytest.raises(ReplayMismatchError, match="replaying env 1's episode"):
        GymVectorEnv(env_id, n_envs=2, episode_length=15).restore_replay(state)
    for e in (env, fresh):
        e.close()


def test_summary_records_what_the_job_did(tmp_path):
    result = run_cli(*TINY, "updates=2", "explorer=gaussian", "logger=none", run_dir=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["settings"] == {"algorithm": "ppo", "updates": 2, "n_envs": 2, "n_steps": 32, "eval_period": 7,
                                   "eval_episodes": 2, "episode_length": 50, "first_run": 0,
                                   "final_episodes": 0}
    assert summary["explorer"] == "gaussian" and summary["config"]["algorithm"]["n_steps"] == 32


def test_launchers_request_the_estimated_memory_and_time():
    """The zoo's job: 18 PyBullet worlds and a rollout of 8,192 steps (1.19 GB measured, 2 of
    them evaluation envs); 2M steps at the assumed 300 env steps/s, with the launcher's margin."""
    from sde_torchrl.jobs.resources import estimate_memory, launcher_request

    conf = validate(compose_config("+experiment=ppo_halfcheetah_bullet"))
    assert 1.2 < estimate_memory(conf).total_gb < 2.0
    assert launcher_request(conf) == {"mem_gb": 3, "timeout_min": 164}
