"""How much memory and time a training job needs, estimated from its sizes before anything is
built: the limit a job is checked against, and what the cluster launchers request per shard.

:func:`estimate_memory` adds up what a job holds, by part; its constants are measured on ball
catching for the episodic estimators and on Pendulum-v1 and HalfCheetahBullet for PPO, A2C and
SAC. :func:`check_memory` refuses, before any work, a job whose estimate exceeds the memory the
machine has available (or ``max_memory_gb``). :func:`estimate_minutes` counts the env steps a
job takes at its env's declared rate; :func:`launcher_request` turns both into a launcher's
request with :data:`MARGIN` on top (``conf/hydra/launcher/*.yaml`` ask for it through the
``sde_memory_gb`` and ``sde_time_min`` resolvers). This module imports neither torch, pybullet
nor the config's schemas, which stand above it: it reads what they declare (see
:func:`estimate_memory`), so ``train.py`` runs it with the config checks.
"""

from __future__ import annotations

import copy
import math
import os
from dataclasses import dataclass
from typing import Any, ClassVar

from sde_torchrl.utils.checks import ArgumentError

GB = 1e9
#: Interpreter, torch, TorchRL and pybullet loaded, one job built with a single small run.
BASE_BYTES = 0.40 * GB
#: Bytes held per number of the kept episodes, with the estimator's intermediates.
WORK_FACTOR = 4 * 4
#: Floats per step row of an env whose sizes are known only once it is made: a quarter of them
#: each the assumed observation and action size.
UNKNOWN_STEP_FLOATS = 64
#: Bytes per learnable parameter and run: the parameter, its gradient, the optimiser's state
#: (Adam: two), the update's and the checkpoint's copies.
PARAMETER_BYTES = 6 * 4
#: Bytes per hidden unit and step of the kept episodes: the actor's activations in the
#: likelihood's graph and their gradients (MLP actors: 12-14 measured).
ACTIVATION_BYTES = 4 * 4
#: Bytes per score (one per kept episode and parameter): the scores, their flattened copy and the
#: estimator's products of them (REINFORCE: 23 measured); ENAC solves its regression in float64.
SCORE_BYTES, FLOAT64_SCORE_BYTES = 6 * 4, 8 * 4
#: Bytes per update for its records (four small tensors of ``runs`` numbers, and their objects).
UPDATE_BYTES = 1000
#: Bytes per step and parameter: GPOMDP's per-step scores of the kept episodes (21 measured), PGPE's
#: drawn parameters and their noise, carried at every step of every episode (12 measured).
STEP_SCORE_BYTES, DRAW_BYTES = 6 * 4, 3 * 4
#: A PPO / A2C / SAC job's interpreter with torch, TorchRL and gymnasium loaded, its job built and trained
#: with 64 × 64 networks on Pendulum-v1 (0.45 GB measured).
ALGORITHM_BASE_BYTES = 0.45 * GB
#: What ``algorithm.compile`` adds: the compiler loaded and the compiled graphs (0.1 GB measured).
COMPILE_BYTES = 0.1 * GB
#: Observation and action sizes of the gymnasium envs of the PPO / A2C / SAC experiments, by a part
#: of ``env.id``; another env is taken to have :data:`UNKNOWN_STEP_FLOATS` ``// 4`` of each.
GYM_DIMENSIONS = {"Pendulum": (3, 1), "MountainCarContinuous": (2, 1), "HalfCheetahBullet": (26, 6),
                  "HopperBullet": (15, 3), "Walker2DBullet": (22, 6), "AntBullet": (28, 8)}
#: Bytes per collected env step (not per env) of a PPO / A2C rollout, an evaluation or a SAC round
#: until its steps are stacked: each step's tensordict, a dozen small tensors (3 kB measured).
STEP_BYTES = 3000
#: Bytes per hidden unit and minibatch row of a PPO / A2C / SAC job's networks trained on it: the
#: activations kept for the backward pass, their gradients and the allocator's slack (measured:
#: PPO 6.7, A2C 5.8, SAC 9.9 over its actor and both Q-networks).
ALGORITHM_ACTIVATION_BYTES = 10
#: Bytes per number of a PPO / A2C rollout: the steps' float32 numbers, GAE's and the minibatches' copies.
ONPOLICY_BYTES_PER_FLOAT = 8
#: Env steps per second of an on-policy job (``algorithm=ppo``), collection and updates together:
#: PPO on HalfCheetahBullet with the zoo's settings ran at 374 on a shared 2-core machine.
ONPOLICY_STEPS_PER_SECOND = 300
#: Env steps per second of a SAC job (``algorithm=sac``), one gradient step per env step: the
#: zoo's HalfCheetahBullet settings ran at 26 on a shared 2-core machine; a little less is assumed.
SAC_STEPS_PER_SECOND = 20
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
    networks: float = 0.0
    buffer: float = 0.0
    batch: float = 0.0

    #: What each part is, for a message (the last three: PPO, A2C and SAC jobs).
    PARTS: ClassVar[dict[str, str]] = {"base": "Python with torch and TorchRL loaded", "worlds": "the simulator worlds",
             "episodes": "the episodes' steps", "actor": "the actor's parameters and activations",
             "scores": "the estimator's per-episode scores", "updates": "the per-update records",
             "networks": "the networks' parameters, gradients and optimiser state", "buffer": "the replay buffer",
             "batch": "the minibatch and the networks' activations over it"}

    @property
    def total(self) -> float:
        return sum(getattr(self, name) for name in self.PARTS)

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


def _sizes(env: Any) -> tuple[int, int]:
    """(observation size, action size) that the env's schema declares, each
    :data:`UNKNOWN_STEP_FLOATS` ``// 4`` where only the made env tells them."""
    sizes = env.sizes()
    return (int(sizes[0]), int(sizes[1])) if sizes is not None else (UNKNOWN_STEP_FLOATS // 4,) * 2


def policy_sizes(conf: Any) -> tuple[int, int]:
    """(learnable parameters per run, hidden units per step) of the job's actor and explorer:
    ``actor=linear`` ``S × A`` (and ``A`` biases), ``actor=mlp`` its layers' weights and biases;
    the SDE explorer's ``σ̂`` (at most one per noise-matrix element, ``A × S``), PGPE's ``σ`` (one
    per actor parameter).

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> from sde_torchrl.config.schemas.envs import MinimizeEnvConf
        >>> env = MinimizeEnvConf(dim=2)
        >>> policy_sizes(Conf(env=env, actor=Conf(hidden=[3], bias=True), explorer=Conf(sharing="element")))
        (23, 3)
        >>> policy_sizes(Conf(env=env, actor=Conf(bias=False), explorer=Conf(schedule="episode")))
        (10, 0)
    """
    observation, action = _sizes(conf.env)
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

    A job of the episodic estimators holds, besides the interpreter, torch and pybullet
    (:data:`BASE_BYTES`):

    - what each env slot holds beside its steps (a simulator world), as the env's schema declares
      (``slot_bytes()``), for ``runs × (episodes_per_update + eval_episodes)`` slots;
    - the episodes of one update and one evaluation, ``[runs, max(N, Q) + eval_episodes, T]`` step
      rows of :func:`step_floats` numbers each (of the sizes the env's schema declares,
      ``sizes()``, or :data:`UNKNOWN_STEP_FLOATS`), and the estimator's work on them:
      :data:`WORK_FACTOR` times the episodes; GPOMDP also keeps one score per step and parameter,
      PGPE each episode's drawn parameters at every step;
    - the actor (:func:`policy_sizes`): its parameters and the explorer's, with their gradients
      and the optimiser's state (:data:`PARAMETER_BYTES` each, per run), and the hidden layers'
      activations over the kept episodes in the likelihood's graph (:data:`ACTIVATION_BYTES` per
      hidden unit and step);
    - the per-episode scores, one per kept episode and parameter (:data:`SCORE_BYTES`);
    - the per-update records (returns, gradient norms, exploration: :data:`UPDATE_BYTES`).

    The constants are measured on ball catching (PyBrain arm, 2 cores, torch CPU, max RSS by
    ``/usr/bin/time -v``: 1.01 GB for 5 runs and 2.84 GB for 20 runs after the first updates),
    the actor's and the scores' on the function-minimisation task with MLP actors. A PPO, A2C or
    SAC job (``algorithm``) is counted by its networks, minibatch, rollout and replay buffer
    instead (:data:`ALGORITHM_BASE_BYTES` and the constants after it, measured on Pendulum-v1 and
    HalfCheetahBullet with networks up to 4096 × 4096 and minibatches up to 20,000).

    What the schemas declare is read, ``False`` where a schema does not declare a trait: the env's
    (:class:`~sde_torchrl.config.schemas.envs.EnvConf`) ``sizes()``, ``slot_bytes()``,
    ``steps_per_second`` and ``size_settings``; the optimizer's ``moments()``; the estimator's
    ``keeps_step_scores``, ``carries_parameter_draws`` and ``solves_in_float64``
    (:class:`~sde_torchrl.config.schemas.estimators.EstimatorConf`) and the explorer's
    ``draws_actor_parameters`` (:class:`~sde_torchrl.config.schemas.policy.PGPEExplorerConf`).

    Args:
        conf: the job's config (``runs``, ``episodes_per_update``, ``episode_queue``,
            ``eval_episodes``, ``env``, ``estimator``; ``actor``, ``explorer`` and ``updates``
            where it has them).
        parameters: learnable parameters per run (``None``: :func:`policy_sizes`).

    Returns:
        The estimate, by part.

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> from sde_torchrl.config.schemas.envs import BallCatchEnvConf
        >>> job = Conf(runs=50, episodes_per_update=1, episode_queue=20, eval_episodes=3, env=BallCatchEnvConf(),
        ...            estimator=Conf())
        >>> estimate_memory(job).total_gb
        6.38
    """
    if getattr(conf, "algorithm", None) is not None:
        return _sac_memory(conf) if hasattr(conf.algorithm, "buffer_size") else _onpolicy_memory(conf)
    observation, action = _sizes(conf.env)
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
    return MemoryEstimate(
        base=BASE_BYTES, worlds=envs * conf.env.slot_bytes(), episodes=episodes,
        actor=conf.runs * (parameters * PARAMETER_BYTES + kept * length * hidden * ACTIVATION_BYTES),
        scores=conf.runs * kept * parameters * (FLOAT64_SCORE_BYTES if getattr(estimator, "solves_in_float64", False)
                                                else SCORE_BYTES),
        updates=getattr(conf, "updates", 0) * (UPDATE_BYTES + 2 * 6 * 4 * conf.runs))


def _onpolicy_memory(conf: Any) -> MemoryEstimate:
    """A PPO or A2C job (``algorithm=ppo``, ``a2c``):

    - the envs (:func:`_env_bytes`, ``n_envs`` of them for training);
    - the networks (:func:`_network_bytes`): the actor (its last hidden layer the SDE features
      ``S``, with ``σ̂``, at most ``A × S``) and the critic (``algorithm.critic_hidden``, else the
      actor's layers);
    - the episodes' steps: the rollout's ``n_steps`` steps (:data:`STEP_BYTES`) of ``n_envs × n_steps``
      rows, each the observation and the next one, action, log-likelihood, flags, rewards and
      GAE's outputs (:data:`ONPOLICY_BYTES_PER_FLOAT` per number), and an evaluation
      (:func:`_evaluation_bytes`);
    - the larger of the minibatch's graph through actor and critic (PPO: ``batch_size`` rows; A2C:
      the whole rollout; :data:`ALGORITHM_ACTIVATION_BYTES` per hidden unit and row) and GAE's pass of the
      critic over the rollout's observations and next observations without gradient (the widest
      layer's input and output, float32).

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> from sde_torchrl.config.schemas.envs import GymEnvConf
        >>> from sde_torchrl.config.schemas.optimizers import AdamOptimizerConf
        >>> job = Conf(env=GymEnvConf(id="m:HalfCheetahBulletEnv-v0", episode_length=1000),
        ...            actor=Conf(hidden=[256, 256]),
        ...            explorer=Conf(schedule="every_n_steps"), optimizer=AdamOptimizerConf(),
        ...            algorithm=Conf(n_envs=16, n_steps=512, batch_size=128, critic_hidden=None, compile=True),
        ...            eval_episodes=10, final_episodes=0)
        >>> estimate_memory(job).total_gb
        1.72
    """
    observation, action = _gym_dimensions(conf)
    alg = conf.algorithm
    hidden = [int(size) for size in conf.actor.hidden]
    critic_hidden = [int(size) for size in (alg.critic_hidden if alg.critic_hidden is not None else hidden)]
    features = hidden[-1] if hidden else observation
    networks = _network_bytes(conf, [observation, *hidden, action], action * features + action,
                              ([observation, *critic_hidden, 1], 1, 0))
    rows = alg.n_envs * alg.n_steps
    graph = getattr(alg, "batch_size", rows) * (sum(hidden) + sum(critic_hidden)) * ALGORITHM_ACTIVATION_BYTES
    advantages = 2 * rows * 2 * max(critic_hidden, default=1) * 4
    rollout = alg.n_steps * STEP_BYTES + rows * (2 * observation + 2 * action + 12) * ONPOLICY_BYTES_PER_FLOAT
    return MemoryEstimate(base=_algorithm_base(conf), worlds=_env_bytes(conf, alg.n_envs),
                          episodes=rollout + _evaluation_bytes(conf, observation, action, features),
                          networks=networks, batch=max(graph, advantages))


def _sac_memory(conf: Any) -> MemoryEstimate:
    """A SAC job (``algorithm=sac``):

    - the envs (:func:`_env_bytes`, one for training);
    - the networks (:func:`_network_bytes`): the actor (as PPO's) and two Q-networks of
      ``[observation, action]`` with the actor's hidden layers, each with its target copy, and
      the critic they were made from;
    - the replay buffer of ``min(buffer_size, env steps)`` transitions as stored (float32
      observation, action, reward and next observation; two flags of a byte), held twice when
      a resumed job loads it (the checkpoint's copy and the buffer's);
    - the minibatch: ``batch_size`` sampled transitions and the actor loss's graph through the
      actor and both Q-networks (:data:`ALGORITHM_ACTIVATION_BYTES` per hidden unit and row);
    - the episodes' steps: a round's ``train_freq`` steps (:data:`STEP_BYTES`) and an evaluation
      (:func:`_evaluation_bytes`).

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> from sde_torchrl.config.schemas.envs import GymEnvConf
        >>> from sde_torchrl.config.schemas.optimizers import AdamOptimizerConf
        >>> job = Conf(env=GymEnvConf(id="m:HalfCheetahBulletEnv-v0", episode_length=1000),
        ...            actor=Conf(hidden=[400, 300]),
        ...            explorer=Conf(schedule="rollout"), optimizer=AdamOptimizerConf(),
        ...            algorithm=Conf(buffer_size=300_000, batch_size=256, train_freq=8, rounds_per_update=125,
        ...                           compile=True), updates=1000, eval_episodes=10, final_episodes=0)
        >>> estimate_memory(job).total_gb
        1.48
    """
    observation, action = _gym_dimensions(conf)
    alg = conf.algorithm
    hidden = [int(size) for size in conf.actor.hidden]
    features = hidden[-1] if hidden else observation
    networks = _network_bytes(conf, [observation, *hidden, action], action * features + action,
                              ([observation + action, *hidden, 1], 2, 3))
    transitions = min(alg.buffer_size, conf.updates * alg.rounds_per_update * alg.train_freq)
    stored = (2 * observation + action + 1) * 4 + 2
    batch = alg.batch_size * (stored + 3 * sum(hidden) * ALGORITHM_ACTIVATION_BYTES)
    return MemoryEstimate(base=_algorithm_base(conf), worlds=_env_bytes(conf, 1),
                          episodes=alg.train_freq * STEP_BYTES + _evaluation_bytes(conf, observation, action, features),
                          networks=networks, buffer=2 * transitions * stored, batch=batch)


def _algorithm_base(conf: Any) -> float:
    """:data:`ALGORITHM_BASE_BYTES`, and :data:`COMPILE_BYTES` with ``algorithm.compile``."""
    return ALGORITHM_BASE_BYTES + (COMPILE_BYTES if getattr(conf.algorithm, "compile", False) else 0.0)


def _gym_dimensions(conf: Any) -> tuple[int, int]:
    """(observation size, action size) of a PPO / A2C / SAC job's gymnasium env
    (:data:`GYM_DIMENSIONS`), the observation with the time feature (``algorithm.time_feature``)."""
    env_id = str(getattr(conf.env, "id", ""))
    observation, action = next((sizes for name, sizes in GYM_DIMENSIONS.items() if name in env_id),
                               (UNKNOWN_STEP_FLOATS // 4, UNKNOWN_STEP_FLOATS // 4))
    return observation + int(bool(getattr(conf.algorithm, "time_feature", False))), action


def _mlp_sizes(layers: list[int]) -> tuple[int, int]:
    """(weights and biases, largest weight matrix) of a fully connected network with these layer
    sizes, input first.

    Examples:
        >>> _mlp_sizes([3, 64, 64, 1])
        (4481, 4096)
    """
    pairs = list(zip(layers[:-1], layers[1:], strict=True))
    return sum(fan_in * fan_out + fan_out for fan_in, fan_out in pairs), max(i * o for i, o in pairs)


def _optimizer_moments(optimizer: Any) -> int:
    """Numbers the ``optimizer`` group's optimiser keeps per parameter, as its schema declares
    (``moments()``: Adam its two moments, RMSprop its average of squares, SGD its momentum);
    without an optimizer (SAC's default, Adam's), 2.

    Examples:
        >>> from sde_torchrl.config.schemas.optimizers import AdamOptimizerConf, SGDOptimizerConf
        >>> _optimizer_moments(AdamOptimizerConf()), _optimizer_moments(SGDOptimizerConf()), _optimizer_moments(None)
        (2, 0, 2)
    """
    return optimizer.moments() if optimizer is not None else 2


def _network_bytes(conf: Any, actor_layers: list[int], actor_extra: int,
                   critic: tuple[list[int], int, int]) -> float:
    """The networks of a PPO / A2C / SAC job, float32: each trained parameter, its gradient and the
    optimiser's moments (:func:`_optimizer_moments`); the actor's parameters also in the best
    policy kept and in its copy at a checkpoint; the critic's copies; and the largest weight
    matrix twice more (the optimiser step's temporary, the checkpoint's digest).

    Args:
        conf: the job's config (its ``optimizer``).
        actor_layers: the actor's layer sizes, observation first.
        actor_extra: the actor's parameters outside those layers (the exploration scale).
        critic: the critic's layer sizes, its trained copies and its other copies (SAC: two
            Q-networks; their targets and the critic they were made from).
    """
    per_trained = 2 + _optimizer_moments(conf.optimizer)
    actor, actor_layer = _mlp_sizes(actor_layers)
    layers, trained, other = critic
    parameters, critic_layer = _mlp_sizes(layers)
    numbers = (per_trained + 2) * (actor + actor_extra) + (trained * per_trained + other) * parameters
    return 4 * (numbers + 2 * max(actor_layer, critic_layer))


def _env_bytes(conf: Any, training: int) -> float:
    """The envs of a PPO / A2C / SAC job: ``training`` ones, the ``eval_episodes`` evaluation envs
    and the final check's (at most ``eval_episodes`` at a time, made beside them), each what the
    env's schema declares (``slot_bytes()``)."""
    check = min(conf.eval_episodes, getattr(conf, "final_episodes", 0) or 0)
    return (training + conf.eval_episodes + check) * conf.env.slot_bytes()


def _evaluation_bytes(conf: Any, observation: int, action: int, features: int) -> float:
    """An evaluation of a PPO / A2C / SAC job: ``eval_episodes`` episodes side by side for
    ``episode_length`` steps (:data:`STEP_BYTES` each), every number of every step held twice
    while the steps are stacked: observations, action, flags and, with an SDE explorer (the one
    whose schema has a noise ``schedule``), the noise matrices of the step and of the next one
    and ``σ̂`` (``A × S`` each) and the features ``S``."""
    sde = getattr(conf.explorer, "schedule", None) is not None
    floats = 2 * observation + (3 * action * features + features + 2 * action if sde else 3 * action) + 10
    length = conf.env.episode_length
    return length * STEP_BYTES + 2 * conf.eval_episodes * length * floats * 4


def estimate_minutes(conf: Any) -> float:
    """Minutes a job needs at its env's ``steps_per_second``: every env step of its training
    episodes (the episode queue's first fill, then ``episodes_per_update`` per update) and
    evaluations.

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> from sde_torchrl.config.schemas.envs import BallCatchEnvConf
        >>> job = Conf(runs=50, updates=500, episodes_per_update=1, episode_queue=20, eval_episodes=3,
        ...            eval_period=20, env=BallCatchEnvConf())
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
    return conf.runs * episodes * conf.env.episode_length / conf.env.steps_per_second / 60


def launcher_request(conf: Any) -> dict[str, int]:
    """What a cluster launcher asks for one job (a shard): the estimates times :data:`MARGIN`,
    rounded up, at least 1 GB and 10 minutes.

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> from sde_torchrl.config.schemas.envs import BallCatchEnvConf
        >>> job = Conf(runs=50, updates=500, episodes_per_update=1, episode_queue=20, eval_episodes=3,
        ...            eval_period=20, env=BallCatchEnvConf(), estimator=Conf())
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
        >>> from sde_torchrl.config.schemas.envs import MinimizeEnvConf
        >>> env = MinimizeEnvConf()
        >>> job = Conf(runs=10**6, episodes_per_update=10, episode_queue=0, eval_episodes=5, env=env,
        ...            estimator=Conf(), max_memory_gb=16)
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
        savings = dominant_setting(conf)
        floor = smallest_job(conf).total
        if limit_gb is not None and (not savings or floor > limit):
            raise ArgumentError("max_memory_gb", limit_gb,
                                f"the job would hold about {estimate.total / GB:.2f} GB (estimate), and about "
                                f"{floor / GB:.2f} GB with every size setting at its smallest "
                                f"({MemoryEstimate.PARTS['base']}: {estimate.base / GB:.2f} GB): a limit of at least "
                                f"{math.ceil(estimate.total / GB * 10) / 10:g}, or null (the memory available)")
        part, held = estimate.largest
        name = next(iter(savings), "runs")
        others = [key for key, saved in savings.items() if key != name and saved >= savings[name] / 2]
        raise ArgumentError(name, _setting(conf, name),
                            f"the job would hold about {estimate.total / GB:.1f} GB (estimate), more than {where}; "
                            f"lower {name} (the largest part, {held / GB:.1f} GB, is {MemoryEstimate.PARTS[part]})"
                            + (f", or {', '.join(others)}" if others else "")
                            + ("; or split the runs into shards (first_run)" if getattr(conf, "runs", 1) > 1 else ""))
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
    smallest.update({f"env.{key}": value for key, value in conf.env.size_settings.items()})
    hidden = getattr(getattr(conf, "actor", None), "hidden", None)
    if hidden:
        smallest["actor.hidden"] = [1] * len(hidden)
    algorithm = getattr(conf, "algorithm", None)
    if algorithm is not None:  # PPO, A2C, SAC: the settings each has
        smallest.update({f"algorithm.{key}": 1 for key in ("n_envs", "n_steps", "batch_size", "buffer_size")})
        if getattr(algorithm, "critic_hidden", None):
            smallest["algorithm.critic_hidden"] = [1] * len(algorithm.critic_hidden)
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
    """A shallow copy of ``conf`` with the dotted ``key`` set to ``value`` (for a what-if
    estimate): of the same type, so that what a schema declares stays, frozen or not."""
    head, _, rest = key.partition(".")
    changed = copy.copy(conf)
    object.__setattr__(changed, head, _changed(getattr(conf, head), rest, value) if rest else value)
    return changed


def smallest_job(conf: Any) -> MemoryEstimate:
    """The estimate of the job with every size setting at its smallest value: what no setting
    but ``max_memory_gb`` can bring below.

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> from sde_torchrl.config.schemas.envs import MinimizeEnvConf
        >>> env = MinimizeEnvConf()
        >>> smallest_job(Conf(runs=4, episodes_per_update=10, episode_queue=0, eval_episodes=5, env=env,
        ...                   estimator=Conf())).total_gb
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
        >>> from sde_torchrl.config.schemas.envs import MinimizeEnvConf
        >>> env = MinimizeEnvConf()
        >>> job = Conf(runs=4, episodes_per_update=10, episode_queue=0, eval_episodes=10**9, env=env,
        ...            estimator=Conf())
        >>> next(iter(dominant_setting(job)))
        'eval_episodes'
    """
    total = estimate_memory(conf).total
    savings = {key: total - estimate_memory(_changed(conf, key, value)).total for key, value in _smallest(conf).items()}
    return dict(sorted(((key, saved) for key, saved in savings.items() if saved > 0),
                       key=lambda item: -item[1]))
