"""How much memory and time a training job needs, estimated from its sizes before anything is
built: the limit a job is checked against, and what the cluster launchers request per shard.

A job holds, besides the interpreter, torch and pybullet (:data:`BASE_BYTES`) (an on-policy job,
``algorithm=ppo``, otherwise: :func:`_onpolicy_memory`; ``algorithm=sac``: :func:`_sac_memory`):

- one simulator world per env slot: ``runs × (episodes_per_update + eval_episodes)`` worlds of
  ball catching (:data:`WORLD_BYTES` each), of gymnasium envs (:data:`GYM_ENV_BYTES`; a PyBullet
  one, a world); the function-minimisation env keeps its state in small tensors;
- the episodes of one update and one evaluation, ``[runs, max(N, Q) + eval_episodes, T]`` step
  rows of :func:`step_floats` numbers each, and the estimator's work on them: :data:`WORK_FACTOR`
  times the episodes; GPOMDP also keeps one score per step and parameter, PGPE each episode's
  drawn parameters at every step;
- the actor (:func:`policy_sizes`): its parameters and the explorer's, with their gradients and
  the optimiser's state (:data:`PARAMETER_BYTES` each, per run), and the hidden layers'
  activations over the kept episodes in the likelihood's graph (:data:`ACTIVATION_BYTES` per
  hidden unit and step);
- the per-episode scores, one per kept episode and parameter (:data:`SCORE_BYTES`);
- the per-update records (returns, gradient norms, exploration: :data:`UPDATE_BYTES`).

The constants are measured on ball catching (PyBrain arm, 2 cores, torch 2.13 CPU, max RSS by
``/usr/bin/time -v``): 1.01 GB for 5 runs and 2.84 GB for 20 runs after the first updates; the
actor's and the scores' on the function-minimisation task with MLP actors (``tests/test_resources.py``).
:func:`check_memory` refuses, before any work, a job whose estimate exceeds the memory the
machine has available (or ``max_memory_gb``), naming the estimate, its largest part and the size
setting whose smallest value would save the most (:func:`dominant_setting`).
The time a job needs (:func:`estimate_minutes`) counts the env steps it takes at
:data:`STEPS_PER_SECOND`, a rate below what one core reaches on a shared machine (ball catching:
2,400 steps/s for 2 jobs on 2 cores with tests beside them). :func:`launcher_request` turns both
into a launcher's request with :data:`MARGIN` on top; ``conf/hydra/launcher/*.yaml`` ask for it
through the ``sde_memory_gb`` and ``sde_time_min`` resolvers. This module imports neither torch
nor pybullet: ``train.py`` runs it with the config checks. Nor does it import the config's
schemas, which stand above it: what an estimator or explorer keeps in memory it reads off the
traits their schemas declare as class attributes (``keeps_step_scores``,
``carries_parameter_draws``, ``solves_in_float64`` of :class:`~sde_torchrl.config.schemas.estimators.EstimatorConf`;
``draws_actor_parameters`` of :class:`~sde_torchrl.config.schemas.policy.PGPEExplorerConf`), ``False`` where
a schema does not declare one.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any, ClassVar

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
#: Bytes per learnable parameter and run: the parameter, its gradient, the optimiser's state
#: (Adam: two), the update's and the checkpoint's copies.
PARAMETER_BYTES = 6 * 4
#: Bytes per hidden unit and step of the kept episodes: the actor's activations in the
#: likelihood's graph and their gradients (MLP actors: 12-14 measured; ``tests/test_resources.py``).
ACTIVATION_BYTES = 4 * 4
#: Bytes per score (one per kept episode and parameter): the scores, their flattened copy and the
#: estimator's products of them (REINFORCE: 23 measured); ENAC solves its regression in float64.
SCORE_BYTES, FLOAT64_SCORE_BYTES = 6 * 4, 8 * 4
#: Bytes per update for its records (four small tensors of ``runs`` numbers, and their objects).
UPDATE_BYTES = 1000
#: Bytes per step and parameter: GPOMDP's per-step scores of the kept episodes (21 measured), PGPE's
#: drawn parameters and their noise, carried at every step of every episode (12 measured).
STEP_SCORE_BYTES, DRAW_BYTES = 6 * 4, 3 * 4
#: One gymnasium env of ``env=gym`` (TorchRL's ``GymEnv`` around it): Pendulum-v1, 15-19 kB measured;
#: a PyBullet env holds a world (:data:`WORLD_BYTES`).
GYM_ENV_BYTES = 20e3
#: Env steps per second and core that a job is assumed to reach (ball catching; the other envs
#: are faster): a conservative rate for the time a launcher requests.
STEPS_PER_SECOND = {"ballcatch": 2000, "other": 20000}
#: Env steps per second of an on-policy job (``algorithm=ppo``), collection and updates together:
#: PPO on HalfCheetahBullet with the zoo's settings ran at 374 on a shared 2-core machine.
ONPOLICY_STEPS_PER_SECOND = 300
#: Env steps per second of a SAC job (``algorithm=sac``), one gradient step per env step: the
#: zoo's HalfCheetahBullet settings ran at 26 on a shared 2-core machine; a little less is assumed.
SAC_STEPS_PER_SECOND = 20
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
        >>> MemoryEstimate(base=4e8, worlds=0, episodes=1e8, actor=3e9).largest
        ('actor', 3000000000.0)
    """

    base: float
    worlds: float
    episodes: float
    actor: float = 0.0
    scores: float = 0.0
    updates: float = 0.0

    #: What each part is, for a message.
    PARTS: ClassVar[dict[str, str]] = {"base": "Python with torch and TorchRL loaded", "worlds": "the simulator worlds",
             "episodes": "the episodes' steps", "actor": "the actor's parameters and activations",
             "scores": "the estimator's per-episode scores", "updates": "the per-update records"}

    @property
    def total(self) -> float:
        return self.base + self.worlds + self.episodes + self.actor + self.scores + self.updates

    @property
    def largest(self) -> tuple[str, float]:
        """The part that holds the most, and its bytes."""
        return max(((name, getattr(self, name)) for name in self.PARTS), key=lambda part: part[1])

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


def policy_sizes(conf: Any) -> tuple[int, int]:
    """(learnable parameters per run, hidden units per step) of the job's actor and explorer:
    ``actor=linear`` ``S × A`` (and ``A`` biases), ``actor=mlp`` its layers' weights and biases;
    the SDE explorer's ``σ̂`` (at most one per noise-matrix element, ``A × S``), PGPE's ``σ`` (one
    per actor parameter).

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> env = Conf(_target_="sde_torchrl.envs.make_minimize_env", dim=2)
        >>> policy_sizes(Conf(env=env, actor=Conf(hidden=[3], bias=True), explorer=Conf(sharing="element")))
        (23, 3)
        >>> policy_sizes(Conf(env=env, actor=Conf(bias=False), explorer=Conf(schedule="episode")))
        (10, 0)
    """
    observation, action, _ = _dimensions(conf.env)
    actor, explorer = getattr(conf, "actor", None), getattr(conf, "explorer", None)
    hidden = [int(size) for size in (getattr(actor, "hidden", None) or [])]
    bias = bool(getattr(actor, "bias", False))
    layers = [observation, *hidden, action]
    weights = sum(fan_in * fan_out + (fan_out if bias else 0) for fan_in, fan_out in zip(layers[:-1], layers[1:],
                                                                                          strict=True))
    pgpe = bool(getattr(explorer, "draws_actor_parameters", False))
    features = observation + int(bool(getattr(conf.env, "constant_feature", False)))
    return weights + (weights if pgpe else action * features + action), sum(hidden)


def keeps_step_scores(conf: Any) -> bool:
    """Whether the job's estimator keeps one score per step and parameter (GPOMDP).

    Such a job also makes and frees megabyte-sized tensors at every update, which is why
    :func:`~sde_torchrl.config.build.run_job` fixes the heap's mmap threshold for it
    (:mod:`sde_torchrl.jobs.heap`).

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> keeps_step_scores(Conf(estimator=Conf(keeps_step_scores=True))), keeps_step_scores(Conf(estimator=None))
        (True, False)
    """
    return bool(getattr(conf.estimator, "keeps_step_scores", False))


def estimate_memory(conf: Any, parameters: int | None = None) -> MemoryEstimate:
    """The memory a job with config ``conf`` (a :class:`~sde_torchrl.config.schemas.train.TrainConf`) holds.

    Args:
        conf: the job's config (``runs``, ``episodes_per_update``, ``episode_queue``,
            ``eval_episodes``, ``env``, ``estimator``; ``actor``, ``explorer`` and ``updates``
            where it has them).
        parameters: learnable parameters per run (``None``: :func:`policy_sizes`).

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
        return _sac_memory(conf) if hasattr(conf.algorithm, "buffer_size") else _onpolicy_memory(conf)
    observation, action, worlds = _dimensions(conf.env)
    counted, hidden = policy_sizes(conf)
    parameters = counted if parameters is None else parameters
    kept = max(conf.episodes_per_update, conf.episode_queue)  # episodes per run in one update
    length = conf.env.episode_length
    steps = conf.runs * (kept + conf.eval_episodes) * length
    estimator = conf.estimator
    episodes = steps * step_floats(observation, action) * WORK_FACTOR
    if getattr(estimator, "carries_parameter_draws", False):  # each step: the episode's drawn parameters and noise
        episodes += steps * parameters * DRAW_BYTES
    if keeps_step_scores(conf):  # one score per step and parameter, training episodes only
        episodes += conf.runs * kept * length * parameters * STEP_SCORE_BYTES
    envs = conf.runs * (conf.episodes_per_update + conf.eval_episodes)
    if "gym" in str(getattr(conf.env, "_target_", "") or ""):  # one gymnasium env per slot
        per_env = WORLD_BYTES if "Bullet" in str(getattr(conf.env, "id", "")) else GYM_ENV_BYTES
    else:
        per_env = WORLD_BYTES if worlds else 0
    return MemoryEstimate(
        base=BASE_BYTES, worlds=envs * per_env, episodes=episodes,
        actor=conf.runs * (parameters * PARAMETER_BYTES + kept * length * hidden * ACTIVATION_BYTES),
        scores=conf.runs * kept * parameters * (FLOAT64_SCORE_BYTES if getattr(estimator, "solves_in_float64", False)
                                                else SCORE_BYTES),
        updates=getattr(conf, "updates", 0) * (UPDATE_BYTES + 2 * 6 * 4 * conf.runs))


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


def _sac_memory(conf: Any) -> MemoryEstimate:
    """A SAC job (``algorithm=sac``): one PyBullet world per env (one training env and the
    evaluation envs, :data:`WORLD_BYTES`), and the replay buffer of ``min(buffer_size, env steps)``
    transitions, each two observations, an action and three scalars of 4 bytes, held twice
    while a checkpoint is written.

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> job = Conf(env=Conf(_target_="sde_torchrl.envs.gym.make_gym_env", id="m:HalfCheetahBulletEnv-v0"),
        ...            algorithm=Conf(buffer_size=300_000, train_freq=8, rounds_per_update=125), updates=1000,
        ...            eval_episodes=10)
        >>> estimate_memory(job).total_gb
        0.83
    """
    observation, action, _ = _dimensions(conf.env)
    alg = conf.algorithm
    worlds = (1 + conf.eval_episodes) if "Bullet" in str(getattr(conf.env, "id", "")) else 0
    transitions = min(alg.buffer_size, conf.updates * alg.rounds_per_update * alg.train_freq)
    return MemoryEstimate(base=BASE_BYTES, worlds=worlds * WORLD_BYTES,
                          episodes=2 * transitions * (2 * observation + action + 3) * 4)


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
        sac = hasattr(conf.algorithm, "buffer_size")
        per_update = conf.algorithm.rounds_per_update * conf.algorithm.train_freq if sac else \
            conf.algorithm.n_envs * conf.algorithm.n_steps
        steps = conf.updates * per_update + evaluations * conf.eval_episodes * conf.env.episode_length
        return steps / (SAC_STEPS_PER_SECOND if sac else ONPOLICY_STEPS_PER_SECOND) / 60
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
        ArgumentError: for the size setting that dominates (:func:`dominant_setting`), or
            ``max_memory_gb`` where it is below what the smallest job holds: naming the estimate,
            the limit, the largest part and the settings to lower.

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> env = Conf(_target_="sde_torchrl.envs.make_minimize_env", episode_length=15, dim=1)
        >>> job = Conf(runs=10**6, episodes_per_update=10, episode_queue=0, eval_episodes=5, env=env,
        ...            estimator=Conf(_target_=""), max_memory_gb=16)
        >>> try:
        ...     check_memory(job)
        ... except ArgumentError as error:
        ...     print(str(error).split(";")[0])
        runs=1000000: the job would hold about 55.2 GB (estimate), more than max_memory_gb=16
    """
    estimate = estimate_memory(conf)
    limit_gb = getattr(conf, "max_memory_gb", None)
    limit = limit_gb * GB if limit_gb is not None else available_memory()
    if estimate.total > limit:
        where = f"max_memory_gb={limit_gb:g}" if limit_gb is not None else \
            f"the {limit / GB:.1f} GB this machine has available"
        if hasattr(getattr(conf, "algorithm", None), "buffer_size"):
            raise ArgumentError("algorithm.buffer_size", conf.algorithm.buffer_size,
                                f"the job would hold about {estimate.total / GB:.1f} GB (estimate), more than {where}; "
                                "lower algorithm.buffer_size")
        if getattr(conf, "algorithm", None) is not None:
            sizes = {"algorithm.n_envs": (conf.algorithm.n_envs, 16),
                     "algorithm.n_steps": (conf.algorithm.n_steps, 512)}
            name = max(sizes, key=lambda key: sizes[key][0] / sizes[key][1])
            raise ArgumentError(name, sizes[name][0],
                                f"the job would hold about {estimate.total / GB:.1f} GB (estimate), more than {where}; "
                                "lower algorithm.n_envs or algorithm.n_steps")
        savings = dominant_setting(conf)
        floor = smallest_job(conf).total
        if limit_gb is not None and (not savings or floor > limit):
            raise ArgumentError("max_memory_gb", limit_gb,
                                f"the job would hold about {estimate.total / GB:.2f} GB (estimate), and about "
                                f"{floor / GB:.2f} GB with every size setting at its smallest "
                                f"({MemoryEstimate.PARTS['base']}: {BASE_BYTES / GB:.2f} GB): a limit of at least "
                                f"{math.ceil(estimate.total / GB * 10) / 10:g}, or null (the memory available)")
        part, held = estimate.largest
        name = next(iter(savings), "runs")
        others = [key for key, saved in savings.items() if key != name and saved >= savings[name] / 2]
        raise ArgumentError(name, _setting(conf, name),
                            f"the job would hold about {estimate.total / GB:.1f} GB (estimate), more than {where}; "
                            f"lower {name} (the largest part, {held / GB:.1f} GB, is {MemoryEstimate.PARTS[part]})"
                            + (f", or {', '.join(others)}" if others else "")
                            + ("; or split the runs into shards (first_run)" if conf.runs > 1 else ""))
    return estimate


def _setting(conf: Any, key: str) -> Any:
    """The value of a dotted config key (``env.episode_length``)."""
    node = conf
    for part in key.split("."):
        node = getattr(node, part)
    return list(node) if isinstance(node, (list, tuple)) else node


def _smallest(conf: Any) -> dict[str, Any]:
    """Each size setting of the job that is above its smallest allowed value, with that value."""
    smallest: dict[str, Any] = {"runs": 1, "episodes_per_update": 1, "episode_queue": 0, "eval_episodes": 1,
                                "env.episode_length": 1, "updates": 1}
    if "minimize" in str(getattr(conf.env, "_target_", "") or ""):
        smallest["env.dim"] = 1
    hidden = getattr(getattr(conf, "actor", None), "hidden", None)
    if hidden:
        smallest["actor.hidden"] = [1] * len(hidden)
    present = {}
    for key, value in smallest.items():
        try:
            current = _setting(conf, key)
        except AttributeError:  # a config without it (a test's namespace)
            continue
        if current != value:
            present[key] = value
    return present


def _changed(conf: Any, key: str, value: Any) -> Any:
    """A shallow copy of ``conf`` with the dotted ``key`` set to ``value`` (for a what-if estimate)."""
    head, _, rest = key.partition(".")
    copy = SimpleNamespace(**vars(conf))
    setattr(copy, head, _changed(getattr(conf, head), rest, value) if rest else value)
    return copy


def smallest_job(conf: Any) -> MemoryEstimate:
    """The estimate of the job with every size setting at its smallest value: what no setting
    but ``max_memory_gb`` can bring below.

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> env = Conf(_target_="sde_torchrl.envs.make_minimize_env", episode_length=15, dim=1)
        >>> smallest_job(Conf(runs=4, episodes_per_update=10, episode_queue=0, eval_episodes=5, env=env,
        ...                   estimator=Conf(_target_=""))).total_gb
        0.4
    """
    for key, value in _smallest(conf).items():
        conf = _changed(conf, key, value)
    return estimate_memory(conf)


def dominant_setting(conf: Any) -> dict[str, float]:
    """The size settings ordered by how much memory setting each to its smallest value would save,
    the most first: the first is the one that dominates the estimate (a setting that saves nothing
    is left out).

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> env = Conf(_target_="sde_torchrl.envs.make_minimize_env", episode_length=15, dim=1)
        >>> job = Conf(runs=4, episodes_per_update=10, episode_queue=0, eval_episodes=10**9, env=env,
        ...            estimator=Conf(_target_=""))
        >>> next(iter(dominant_setting(job)))
        'eval_episodes'
    """
    total = estimate_memory(conf).total
    savings = {key: total - estimate_memory(_changed(conf, key, value)).total for key, value in _smallest(conf).items()}
    return dict(sorted(((key, saved) for key, saved in savings.items() if saved > 0),
                       key=lambda item: -item[1]))
