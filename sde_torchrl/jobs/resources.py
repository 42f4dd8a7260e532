"""How much memory and time a training job needs, estimated from its sizes before anything is
built: the limit a job is checked against, and what the cluster launchers request per shard.

A job holds, besides the interpreter, torch and pybullet (:data:`BASE_BYTES`) (an on-policy job,
``algorithm=ppo``, otherwise: :func:`_onpolicy_memory`):

- one simulator world per env slot: ``runs × (episodes_per_update + eval_episodes)`` worlds of
  ball catching (:data:`WORLD_BYTES` each; the function-minimisation and gymnasium envs keep
  their state in small tensors);
- the episodes of one update and one evaluation, ``[runs, max(N, Q) + eval_episodes, T]`` step
  rows of :func:`step_floats` numbers each, and the estimator's work on them (the likelihood's
  graph, the per-episode scores): :data:`WORK_FACTOR` times the episodes; GPOMDP also keeps one
  score per step and parameter.

The constants are measured on ball catching (PyBrain arm, 2 cores, torch 2.13 CPU, max RSS by
``/usr/bin/time -v``): 1.01 GB for 5 runs and 2.84 GB for 20 runs after the first updates.
:func:`check_memory` refuses, before any work, a job whose estimate exceeds the memory the
machine has available (or ``max_memory_gb``), naming the estimate and the settings to change.
The time a job needs (:func:`estimate_minutes`) counts the env steps it takes at
:data:`STEPS_PER_SECOND`, a rate below what one core reaches on a shared machine (ball catching:
2,400 steps/s for 2 jobs on 2 cores with tests beside them). :func:`launcher_request` turns both
into a launcher's request with :data:`MARGIN` on top; ``conf/hydra/launcher/*.yaml`` ask for it
through the ``sde_memory_gb`` and ``sde_time_min`` resolvers. This module imports neither torch
nor pybullet: ``train.py`` runs it with the config checks.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

from sde_torchrl.utils.checks import ArgumentError

GB = 1e9
#: Interpreter, torch, TorchRL and pybullet loaded, one job built with a single small run.
BASE_BYTES = 0.40 * GB
#: One ball-catching world (the PyBrain arm's 15 hinges, the ball, their contacts).
WORLD_BYTES = 28e6
#: Bytes held per number of the kept episodes, with the estimator's intermediates.
WORK_FACTOR = 4 * 4
#: Floats per step row of a gymnasium env whose spaces are not known before it is made.
GYM_STEP_FLOATS = 64
#: Env steps per second and core that a job is assumed to reach (ball catching; the other envs
#: are faster): a conservative rate for the time a launcher requests.
STEPS_PER_SECOND = {"ballcatch": 2000, "other": 20000}
#: Env steps per second of an on-policy job (``algorithm=ppo``), collection and updates together:
#: PPO on HalfCheetahBullet with the zoo's settings ran at 374 on a shared 2-core machine.
ONPOLICY_STEPS_PER_SECOND = 300
#: Bytes per number of an on-policy rollout: its tensors, and what GAE and the minibatches copy
#: (measured: 0.25 GB for 8,192 steps of 3,688 numbers).
ONPOLICY_BYTES_PER_FLOAT = 8
#: Factor on the estimates for a launcher's request.
MARGIN = 1.3


@dataclass(frozen=True)
class MemoryEstimate:
    """A job's estimated memory, in bytes, by what holds it.

    Examples:
        >>> MemoryEstimate(base=4e8, worlds=6e8, episodes=2e8).total_gb
        1.2
    """

    base: float
    worlds: float
    episodes: float

    @property
    def total(self) -> float:
        return self.base + self.worlds + self.episodes

    @property
    def total_gb(self) -> float:
        return round(self.total / GB, 2)


def step_floats(observation: int, action: int) -> int:
    """Numbers per step row: observation and features, the next observation, the action, its
    pre-squash sample and mean, the SDE noise matrix ``A × S`` and a few scalars (reward,
    done flags, step count, initial-state flag).

    Examples:
        >>> step_floats(3, 4)  # ball catching
        41
    """
    return 3 * observation + 3 * action + observation * action + 8


def _dimensions(env: Any) -> tuple[int, int, bool]:
    """(observation size, action size, simulator worlds?) of an env config."""
    target = str(getattr(env, "_target_", "") or "")
    if "ballcatch" in target:
        return 3, 4, True
    if "minimize" in target:
        dim = int(getattr(env, "dim", 1) or 1)
        return dim, dim, False
    return GYM_STEP_FLOATS // 4, GYM_STEP_FLOATS // 4, False


def keeps_step_scores(conf: Any) -> bool:
    """Whether the job's estimator keeps one score per step and parameter (GPOMDP).

    Such a job also makes and frees megabyte-sized tensors at every update, which is why
    :func:`~sde_torchrl.config.build.run_job` fixes the heap's mmap threshold for it
    (:mod:`sde_torchrl.jobs.heap`).

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> keeps_step_scores(Conf(estimator=Conf(_target_="sde_torchrl.objectives.estimators.GPOMDPEstimator")))
        True
    """
    return str(getattr(conf.estimator, "_target_", "")).endswith("GPOMDPEstimator")


def estimate_memory(conf: Any, parameters: int | None = None) -> MemoryEstimate:
    """The memory a job with config ``conf`` (a :class:`~sde_torchrl.config.schemas.TrainConf`) holds.

    Args:
        conf: the job's config (``runs``, ``episodes_per_update``, ``episode_queue``,
            ``eval_episodes``, ``env``, ``estimator``).
        parameters: learnable parameters per run, for GPOMDP's per-step scores (``None``: from
            the observation and action sizes of a linear controller and one ``σ̂`` per element).

    Returns:
        The estimate, by part.

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> env = Conf(_target_="sde_torchrl.envs.ballcatch.batched.make_ballcatch_env", episode_length=500)
        >>> job = Conf(runs=50, episodes_per_update=1, episode_queue=20, eval_episodes=3, env=env,
        ...            estimator=Conf(_target_="sde_torchrl.objectives.estimators.ReinforceEstimator"))
        >>> estimate_memory(job).total_gb
        6.38
    """
    if getattr(conf, "algorithm", None) is not None:
        return _onpolicy_memory(conf)
    observation, action, worlds = _dimensions(conf.env)
    steps = conf.runs * (max(conf.episodes_per_update, conf.episode_queue) + conf.eval_episodes) * \
        conf.env.episode_length
    floats = step_floats(observation, action)
    if keeps_step_scores(conf):
        floats += 2 * (parameters if parameters is not None else 2 * observation * action)
    world_count = conf.runs * (conf.episodes_per_update + conf.eval_episodes) if worlds else 0
    return MemoryEstimate(base=BASE_BYTES, worlds=world_count * WORLD_BYTES, episodes=steps * floats * WORK_FACTOR)


def _onpolicy_memory(conf: Any) -> MemoryEstimate:
    """An on-policy job (``algorithm=ppo``): one PyBullet world per env (training and evaluation;
    30 MB each measured on HalfCheetah, :data:`WORLD_BYTES`), and one rollout of
    ``n_envs × n_steps`` steps whose rows hold, as :func:`step_floats` counts, observations, actions
    and scalars, and the SDE noise matrix and ``σ̂`` (``A × S`` each) over the actor's last hidden
    layer (``S`` features, held twice).

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> job = Conf(env=Conf(_target_="sde_torchrl.envs.gym.make_gym_env", id="m:HalfCheetahBulletEnv-v0"),
        ...            actor=Conf(hidden=[256, 256]), algorithm=Conf(n_envs=16, n_steps=512), eval_episodes=10)
        >>> estimate_memory(job).total_gb
        1.71
    """
    observation, action, _ = _dimensions(conf.env)
    features = conf.actor.hidden[-1] if conf.actor.hidden else observation
    floats = 3 * observation + 3 * action + 2 * action * features + 2 * features + 8
    worlds = (conf.algorithm.n_envs + conf.eval_episodes) if "Bullet" in str(getattr(conf.env, "id", "")) else 0
    steps = conf.algorithm.n_envs * conf.algorithm.n_steps
    return MemoryEstimate(base=BASE_BYTES, worlds=worlds * WORLD_BYTES,
                          episodes=steps * floats * ONPOLICY_BYTES_PER_FLOAT)


def estimate_minutes(conf: Any) -> float:
    """Minutes a job needs at :data:`STEPS_PER_SECOND`: every env step of its training episodes
    (the episode queue's first fill, then ``episodes_per_update`` per update) and evaluations.

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> env = Conf(_target_="sde_torchrl.envs.ballcatch.batched.make_ballcatch_env", episode_length=500)
        >>> job = Conf(runs=50, updates=500, episodes_per_update=1, episode_queue=20, eval_episodes=3,
        ...            eval_period=20, env=env)
        >>> round(estimate_minutes(job))
        124
    """
    evaluations = (conf.updates // conf.eval_period if conf.eval_period else 0) + 1
    if getattr(conf, "algorithm", None) is not None:
        steps = conf.updates * conf.algorithm.n_envs * conf.algorithm.n_steps + \
            evaluations * conf.eval_episodes * conf.env.episode_length
        return steps / ONPOLICY_STEPS_PER_SECOND / 60
    episodes = max(conf.episode_queue - conf.episodes_per_update, 0) + conf.updates * conf.episodes_per_update \
        + evaluations * conf.eval_episodes
    rate = STEPS_PER_SECOND["ballcatch" if _dimensions(conf.env)[2] else "other"]
    return conf.runs * episodes * conf.env.episode_length / rate / 60


def launcher_request(conf: Any) -> dict[str, int]:
    """What a cluster launcher asks for one job (a shard): the estimates times :data:`MARGIN`,
    rounded up, at least 1 GB and 10 minutes.

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> env = Conf(_target_="sde_torchrl.envs.ballcatch.batched.make_ballcatch_env", episode_length=500)
        >>> job = Conf(runs=50, updates=500, episodes_per_update=1, episode_queue=20, eval_episodes=3,
        ...            eval_period=20, env=env,
        ...            estimator=Conf(_target_="sde_torchrl.objectives.estimators.ReinforceEstimator"))
        >>> launcher_request(job)
        {'mem_gb': 9, 'timeout_min': 162}
    """
    return {"mem_gb": max(1, math.ceil(MARGIN * estimate_memory(conf).total / GB)),
            "timeout_min": max(10, math.ceil(MARGIN * estimate_minutes(conf)))}


def available_memory() -> float:
    """Bytes this machine has available now (``MemAvailable``, else the physical memory).

    Examples:
        >>> available_memory() > 0
        True
    """
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def check_memory(conf: Any) -> MemoryEstimate:
    """Refuses a job whose estimated memory exceeds ``conf.max_memory_gb`` (or, if that is
    ``None``, the memory available now), before anything is built.

    Raises:
        ArgumentError: naming the estimate, the limit and the settings that size it.

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> env = Conf(_target_="sde_torchrl.envs.make_minimize_env", episode_length=15, dim=1)
        >>> job = Conf(runs=10**6, episodes_per_update=10, episode_queue=0, eval_episodes=5, env=env,
        ...            estimator=Conf(_target_=""), max_memory_gb=16)
        >>> try:
        ...     check_memory(job)
        ... except ArgumentError as error:
        ...     print(str(error).split(";")[0])
        runs=1000000: the job would hold about 54.4 GB (estimate), more than max_memory_gb=16
    """
    estimate = estimate_memory(conf)
    limit_gb = getattr(conf, "max_memory_gb", None)
    limit = limit_gb * GB if limit_gb is not None else available_memory()
    if estimate.total > limit:
        where = f"max_memory_gb={limit_gb:g}" if limit_gb is not None else \
            f"the {limit / GB:.1f} GB this machine has available"
        if getattr(conf, "algorithm", None) is not None:
            sizes = {"algorithm.n_envs": (conf.algorithm.n_envs, 16),
                     "algorithm.n_steps": (conf.algorithm.n_steps, 512)}
            name = max(sizes, key=lambda key: sizes[key][0] / sizes[key][1])
            raise ArgumentError(name, sizes[name][0],
                                f"the job would hold about {estimate.total / GB:.1f} GB (estimate), more than {where}; "
                                "lower algorithm.n_envs or algorithm.n_steps")
        sizes = {"runs": (conf.runs, 1), "episodes_per_update": (conf.episodes_per_update, 10),
                 "episode_queue": (conf.episode_queue, 20),
                 "env.episode_length": (conf.env.episode_length, 500 if _dimensions(conf.env)[2] else 200)}
        name = max(sizes, key=lambda key: sizes[key][0] / sizes[key][1])  # the most above a usual value
        raise ArgumentError(name, sizes[name][0],
                            f"the job would hold about {estimate.total / GB:.1f} GB (estimate), more than {where}; "
                            "lower runs, episodes_per_update, episode_queue or env.episode_length, or split the "
                            "runs into shards (first_run)")
    return estimate
