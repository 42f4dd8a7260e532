"""Limits before work: a job's memory is estimated from its sizes and a job
that cannot fit is refused at once, naming the estimate and the setting; a slow first update
says what it is doing."""

from __future__ import annotations

import logging
import re
import time

import pytest
from _helpers import REPO, build, compose_config, own_stderr_lines, run_cli

from sde_torchrl.config.errors import describe_error
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.jobs.resources import GB, estimate_memory, launcher_request
from sde_torchrl.trainers.job import Job


@pytest.mark.parametrize("override, key", [("runs=1000000", "runs"),
                                           ("episodes_per_update=10000000", "episodes_per_update"),
                                           ("env.episode_length=100000000", "env.episode_length")])
def test_absurd_sizes_are_refused_at_once_in_one_line(tmp_path, override, key):
    start = time.monotonic()
    result = run_cli("+experiment=minimize", override, run_dir=tmp_path / "run")
    elapsed = time.monotonic() - start
    assert result.returncode == 2, result.stderr[-2000:]
    lines = own_stderr_lines(result.stderr)
    assert len(lines) == 1 and lines[0].startswith(f"error: {override}: the job would hold about "), lines
    assert f"GB this machine has available; lower {key} (the largest part, " in lines[0]
    # refused before anything is allocated: building a job of this size would take minutes and
    # far more memory; the bound is loose so that a loaded machine's start-up cannot fail it
    assert elapsed < 30, f"{elapsed:.1f} s"
    assert not (tmp_path / "run" / "metrics.csv").exists()


def test_max_memory_gb_sets_the_limit():
    ballcatch = ("+experiment=ballcatch_reinforce", "runs=5")
    assert estimate_memory(validate(compose_config(*ballcatch))).total_gb == pytest.approx(1.0, abs=0.05)
    with pytest.raises(Exception) as info:
        validate(compose_config(*ballcatch, "max_memory_gb=0.8"))
    assert describe_error(info.value).startswith("runs=5: the job would hold about 1.0 GB (estimate), more than "
                                                 "max_memory_gb=0.8; ")
    validate(compose_config(*ballcatch, "max_memory_gb=1.2"))


#: Max RSS of ``+experiment=ballcatch_reinforce runs=N`` measured on this machine (``/usr/bin/time -v``, 2-3 updates).
MEASURED_GB = {5: 1.01, 20: 2.84, 50: 6.52}


@pytest.mark.parametrize("runs, measured_gb", MEASURED_GB.items())
def test_ballcatch_estimates_grow_with_the_worlds(runs, measured_gb):
    """Max RSS measured on this machine (``/usr/bin/time -v``, 2-3 updates): within 30 %."""
    conf = validate(compose_config("+experiment=ballcatch_reinforce", f"runs={runs}", "max_memory_gb=1000"))
    estimate = estimate_memory(conf)
    assert estimate.worlds == runs * 4 * 28e6  # one training world and three evaluation worlds per run
    if measured_gb is not None:
        assert estimate.total / GB == pytest.approx(measured_gb, rel=0.3)


def test_a_slow_first_update_says_what_it_is_doing(monkeypatch, caplog, tmp_path):
    trainer = build("runs=2", "updates=2", "episodes_per_update=4")
    trainer.first_update_notice_s = 0.0
    original = trainer.update
    monkeypatch.setattr(trainer, "update", lambda k: (time.sleep(0.3), original(k))[1])
    with caplog.at_level(logging.INFO, logger="sde_torchrl.trainers.job"):
        trainer.train(tmp_path)
    notices = [r.getMessage() for r in caplog.records if "still running" in r.getMessage()]
    assert notices == ["update 1 of 2 still running after 0 s: collecting 4 episodes of 15 steps for each of 2 "
                       "runs, then estimating the gradient"]


def test_the_guides_memory_figures_are_the_estimates_and_the_measurements():
    """The figures ``docs/guide/guarantees.md`` quotes are the estimator's (and the measurements above)."""
    text = " ".join((REPO / "docs" / "guide" / "guarantees.md").read_text().split())
    runs = sorted(MEASURED_GB)
    estimates = [estimate_memory(validate(compose_config("+experiment=ballcatch_reinforce", f"runs={n}",
                                                         "max_memory_gb=1000")))
                 .total / GB for n in runs]
    quoted = (f"{' / '.join(f'{e:.1f}' for e in estimates)} GB estimated for {' / '.join(map(str, runs))} runs, "
              f"{' / '.join(f'{MEASURED_GB[n]:.2f}' for n in runs)} GB measured")
    assert quoted in text
    request = launcher_request(validate(compose_config("+experiment=ballcatch_reinforce", "runs=50",
                                                       "max_memory_gb=1000")))
    shard = re.search(r"a 50-run ball-catching shard: (\d+) GB, (\d+) min", text)
    assert shard and (int(shard[1]), int(shard[2])) == (request["mem_gb"], request["timeout_min"])


# ------------------------------------------------ the actor and every size setting

#: Max RSS (``/usr/bin/time -f %M``) of ``+experiment=minimize actor=mlp ... updates=2 eval_period=0``
#: on this machine, GB.
MEASURED_MLP_GB = {
    ("actor.hidden=[2000]", "runs=200"): 1.44,
    ("actor.hidden=[4000]", "runs=200"): 2.30,
    ("actor.hidden=[1000,1000]", "runs=10"): 2.56,
    ("actor.hidden=[500,500]", "runs=10"): 0.97,
    ("actor.hidden=[500,500]", "runs=10", "estimator=enac"): 1.11,
    ("actor.hidden=[500,500]", "runs=10", "estimator=gpomdp"): 8.29,
    ("actor.hidden=[500,500]", "runs=10", "explorer=pgpe", "estimator=pgpe"): 11.59,
}


@pytest.mark.parametrize("overrides, measured_gb", MEASURED_MLP_GB.items())
def test_mlp_actors_are_estimated_from_their_parameters_and_activations(overrides, measured_gb):
    """The estimate covers what an MLP job was measured to hold, by at most 35 % more."""
    conf = validate(compose_config("+experiment=minimize", "actor=mlp", *overrides, "updates=2", "eval_period=0",
                                   "max_memory_gb=1000"))
    assert measured_gb <= estimate_memory(conf).total / GB <= 1.35 * measured_gb


@pytest.mark.parametrize("overrides, key, part", [
    # estimated at 0.4 GB before: died on a 16 GB allocation
    (("actor=mlp", "actor.hidden=[1000000000]"), "actor.hidden", "the actor's parameters and activations"),
    (("actor=mlp", "actor.hidden=[30000, 30000]"), "actor.hidden", "the estimator's per-episode scores"),
    # blamed on runs=4 before
    (("+experiment=minimize", "eval_episodes=1000000000"), "eval_episodes", "the episodes' steps"),
    (("+experiment=minimize", "episode_queue=100000000"), "episode_queue", "the episodes' steps"),
    (("+experiment=minimize", "env.dim=3000"), "env.dim", "the episodes' steps"),
    (("+experiment=minimize", "updates=10000000000"), "updates", "the per-update records"),
    (("+experiment=ballcatch_reinforce", "runs=2000"), "runs", "the simulator worlds"),
])
def test_the_setting_that_dominates_is_named(overrides, key, part):
    with pytest.raises(Exception) as info:
        validate(compose_config(*overrides, "max_memory_gb=16"))
    line = describe_error(info.value)
    assert line.startswith(f"{key}="), line
    assert "more than max_memory_gb=16; lower " + key + " (the largest part, " in line and f"GB, is {part})" in line


def test_a_limit_below_any_job_names_max_memory_gb():
    """``max_memory_gb=0.01`` was blamed on ``runs=4``: no setting but the limit helps."""
    with pytest.raises(Exception) as info:
        validate(compose_config("+experiment=minimize", "max_memory_gb=0.01"))
    assert describe_error(info.value) == (
        "max_memory_gb=0.01: the job would hold about 0.40 GB (estimate), and about 0.40 GB with every size "
        "setting at its smallest (Python with torch and TorchRL loaded: 0.40 GB): a limit of at least 0.5, or null "
        "(the memory available)")


def test_a_wide_actor_over_many_runs_is_refused_before_anything_is_written(tmp_path):
    """``actor.hidden=[20000] runs=1000`` passed the estimate, started metrics.csv and died after
    28 s on a 12 GB allocation (its activations: 1000 runs × 10 episodes × 15 steps × 20000)."""
    start = time.monotonic()
    result = run_cli("actor=mlp", "actor.hidden=[20000]", "runs=1000", "max_memory_gb=16", run_dir=tmp_path / "run")
    assert result.returncode == 2, result.stderr[-2000:]
    lines = own_stderr_lines(result.stderr)
    assert len(lines) == 1 and lines[0].startswith("error: runs=1000: the job would hold about "), lines
    assert "the actor's parameters and activations), or actor.hidden" in lines[0]
    assert time.monotonic() - start < 6
    assert not (tmp_path / "run" / "metrics.csv").exists()


def test_a_job_says_what_it_does_within_seconds(monkeypatch, caplog):
    """``+experiment=pendulum runs=3000 updates=1`` passed the estimate and said nothing for
    minutes: 45,000 gymnasium envs take about 3 ms each to make, then its first update steps them.
    Now a slow build says so after 5 s and counts the envs every 10 s, and a slow first update
    says so after 10 s."""
    from sde_torchrl.config import build as build_module
    from sde_torchrl.config.build import build_trainer
    from sde_torchrl.envs import gym as gym_module

    assert build_module.BUILD_NOTICE_S <= 5 and gym_module.MAKE_PROGRESS_S <= 10
    assert Job.first_update_notice_s <= 10
    monkeypatch.setattr(build_module, "BUILD_NOTICE_S", 0.0)
    monkeypatch.setattr(gym_module, "MAKE_PROGRESS_S", 0.0)
    made = gym_module.GymEnv
    monkeypatch.setattr(gym_module, "GymEnv", lambda *args, **kwargs: (time.sleep(0.05), made(*args, **kwargs))[1])
    with caplog.at_level(logging.INFO):
        build_trainer(compose_config("+experiment=pendulum", "runs=2", "episodes_per_update=2", "eval_episodes=1",
                                     "logger=none"))
    lines = [r.getMessage() for r in caplog.records]
    assert ("still making the envs after 0 s: 2 runs × (2 training + 1 evaluation) episodes side by side, one env "
            "(Pendulum-v1) each; training starts once they are made") in lines
    counts = [line for line in lines if line.startswith("making ")]
    assert counts[0].startswith("making 4 Pendulum-v1 envs (2 runs × 2 training episodes): 1 made after ")
    assert counts[-1].startswith("making 2 Pendulum-v1 envs (2 runs × 1 evaluation episodes): 1 made after ")


#: The estimate (bytes) and the policy's sizes of each experiment, as the estimators' and explorers'
#: names decided them before their schemas declared what they keep in memory.
ESTIMATES = {"ballcatch_reinforce": (520082112, (28, 0)), "ballcatch_enac": (520086592, (28, 0)),
             "ballcatch_gpomdp": (526802112, (28, 0)), "ballcatch_pgpe": (523392096, (24, 0)),
             "minimize2d_mlp": (406650160, (23, 3))}


@pytest.mark.parametrize("experiment", sorted(ESTIMATES))
def test_the_estimate_reads_the_schemas_traits(experiment):
    """Each estimator's and explorer's schema says what it keeps (GPOMDP its per-step scores, PGPE
    its draws, ENAC its float64 regression, PGPE's explorer the actor's parameters): the estimate
    reads those traits, and gives what it gave when it read the ``_target_`` names."""
    from sde_torchrl.jobs.resources import keeps_step_scores, policy_sizes

    conf = validate(compose_config(f"+experiment={experiment}", "max_memory_gb=1000"))
    target = conf.estimator._target_.rsplit(".", 1)[-1]
    assert (conf.estimator.keeps_step_scores, conf.estimator.carries_parameter_draws,
            conf.estimator.solves_in_float64) == (target == "GPOMDPEstimator", target == "PGPEEstimator",
                                                  target == "ENACEstimator")
    assert keeps_step_scores(conf) == (target == "GPOMDPEstimator")
    draws = conf.explorer._target_.endswith("ParameterExplorer")
    assert getattr(conf.explorer, "draws_actor_parameters", False) == draws
    assert (estimate_memory(conf).total, policy_sizes(conf)) == ESTIMATES[experiment]


# ------------------------------------------------ PPO, A2C and SAC: networks, minibatches, replay buffer

#: Max RSS (``/usr/bin/time -v``) of ``python train.py`` with these overrides, GB, measured on this
#: machine (2 cores shared with a sweep on both, 23 GB, torch 2.13 CPU, TorchRL 0.14): 2 updates,
#: evaluated after each, the checkpoint written.
PPO_PENDULUM = ("algorithm=ppo", "env=gym", "env.id=Pendulum-v1", "algorithm.n_steps=64", "algorithm.batch_size=64",
                "algorithm.n_epochs=1", "updates=2", "eval_episodes=1", "eval_period=1", "logger=none")
SAC_PENDULUM = ("algorithm=sac", "env=gym", "env.id=Pendulum-v1", "env.episode_length=50", "algorithm.train_freq=4",
                "algorithm.learning_starts=4", "algorithm.rounds_per_update=2", "algorithm.batch_size=64",
                "algorithm.buffer_size=1000", "updates=2", "eval_episodes=1", "eval_period=1", "logger=none")
WIDE_BATCH = ("actor.hidden=[1024,1024]", "algorithm.n_envs=8", "algorithm.n_steps=1024")
MEASURED_ALGORITHM_GB = {
    "ppo-64": ((*PPO_PENDULUM, "actor.hidden=[64,64]"), 0.453),
    "ppo-1024": ((*PPO_PENDULUM, "actor.hidden=[1024,1024]"), 0.481),
    "ppo-4096": ((*PPO_PENDULUM, "actor.hidden=[4096,4096]"), 1.216),
    "ppo-minibatch-8192": ((*PPO_PENDULUM, *WIDE_BATCH, "algorithm.batch_size=8192"), 0.734),
    "ppo-rollout-2x20000": (("algorithm=ppo", "env=gym", "env.id=Pendulum-v1", "actor.hidden=[16,16]",
                             "algorithm.n_envs=2", "algorithm.n_steps=20000", "algorithm.batch_size=64",
                             "algorithm.n_epochs=1", "updates=1", "eval_episodes=1", "logger=none"), 0.515),
    "ppo-halfcheetah-zoo": (("+experiment=ppo_halfcheetah_bullet", "updates=2", "algorithm.n_epochs=1", "eval_period=1",
                             "logger=none"), 1.542),
    "a2c-rollout-8x1024": (("algorithm=a2c", "env=gym", "env.id=Pendulum-v1", "updates=2", "eval_episodes=1",
                            "eval_period=1", "logger=none", *WIDE_BATCH), 0.694),
    "sac-64": ((*SAC_PENDULUM, "actor.hidden=[64,64]"), 0.455),
    "sac-1024": ((*SAC_PENDULUM, "actor.hidden=[1024,1024]"), 0.517),
    "sac-4096": ((*SAC_PENDULUM, "actor.hidden=[4096,4096]"), 1.747),
    "sac-minibatch-20000": ((*SAC_PENDULUM, "actor.hidden=[256,256]", "algorithm.batch_size=20000",
                             "algorithm.buffer_size=20000"), 0.760),
}


@pytest.mark.parametrize("overrides, measured_gb", MEASURED_ALGORITHM_GB.values(), ids=MEASURED_ALGORITHM_GB)
def test_algorithm_estimates_follow_the_networks_and_the_minibatch(overrides, measured_gb):
    """The estimate of a PPO / A2C / SAC job is within 35 % of its measured max RSS."""
    conf = validate(compose_config(*overrides, "max_memory_gb=1000"))
    assert estimate_memory(conf).total / GB == pytest.approx(measured_gb, rel=0.35)


def test_the_guide_quotes_the_algorithm_measurements():
    """``docs/guide/guarantees.md`` quotes the range of the jobs measured above and how far off their estimates are."""
    text = " ".join((REPO / "docs" / "guide" / "guarantees.md").read_text().split())
    measured = [gb for _, gb in MEASURED_ALGORITHM_GB.values()]
    ratios = [estimate_memory(validate(compose_config(*overrides, "max_memory_gb=1000"))).total / GB / gb - 1
              for overrides, gb in MEASURED_ALGORITHM_GB.values()]
    assert (f"jobs measured {min(measured):.2f}-{max(measured):.2f} GB are estimated {round(-100 * min(ratios))} % "
            f"below to {round(100 * max(ratios))} % above") in text


@pytest.mark.parametrize("overrides, key, part", [
    # the actor's layers make it big, not the rollout's n_envs (whose steps hold no SDE noise)
    (("+experiment=ppo_hopper_bullet", "actor.hidden=[100000,100000]"), "actor.hidden",
     "the networks' parameters, gradients and optimiser state"),
    # a critic of 160 GB
    (("+experiment=ppo_hopper_bullet", "algorithm.critic_hidden=[200000,200000]"), "algorithm.critic_hidden",
     "the networks' parameters, gradients and optimiser state"),
    (("+experiment=a2c_hopper_bullet", "algorithm.critic_hidden=[200000,200000]"), "algorithm.critic_hidden",
     "the networks' parameters, gradients and optimiser state"),
    (("+experiment=sac_hopper_bullet", "actor.hidden=[30000,30000]"), "actor.hidden",
     "the networks' parameters, gradients and optimiser state"),
    # a buffer as large as the minibatch (with the experiment's buffer it is refused as larger than that)
    (("+experiment=sac_hopper_bullet", "algorithm.batch_size=100000000", "algorithm.buffer_size=100000000"),
     "algorithm.batch_size", "the minibatch and the networks' activations over it"),
    (("+experiment=a2c_hopper_bullet", "algorithm.n_steps=3000000"), "algorithm.n_steps",
     "the minibatch and the networks' activations over it"),
])
def test_an_algorithm_jobs_setting_that_dominates_is_named(overrides, key, part):
    with pytest.raises(Exception) as info:
        validate(compose_config(*overrides, "max_memory_gb=16"))
    line = describe_error(info.value)
    assert line.startswith(f"{key}="), line
    assert f"more than max_memory_gb=16; lower {key} (the largest part, " in line and f"GB, is {part})" in line


def test_a_wide_ppo_actor_is_refused_in_one_line_before_anything_is_built(tmp_path):
    """``+experiment=ppo_hopper_bullet actor.hidden=[100000,100000]``: the actor's first 40 GB
    layer would fail to allocate after seconds, with the allocator's text; the job is refused
    before, in one line, with exit 2."""
    result = run_cli("+experiment=ppo_hopper_bullet", "actor.hidden=[100000,100000]", "max_memory_gb=16",
                     run_dir=tmp_path / "run")
    assert result.returncode == 2, result.stderr[-2000:]
    lines = own_stderr_lines(result.stderr)
    assert len(lines) == 1 and lines[0].startswith("error: actor.hidden=[100000, 100000]: the job would hold "
                                                   "about "), lines
    assert not (tmp_path / "run" / "metrics.csv").exists()
