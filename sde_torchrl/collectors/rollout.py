"""Whole-episode collection: :func:`collect_episodes`, the one entry point, and the paths it picks.

Every update needs ``N`` fresh whole episodes of ``T`` steps. ``env.rollout(T, policy,
break_when_any_done=False)`` gives them for any env and policy, but builds, transforms and stacks
a TensorDict at every step. Where the env and the policy allow it, the same episodes come from a
faster path. :func:`collect_episodes` tries the paths in this order and takes the first whose
eligibility function accepts the env and the policy:

1. **Linear episodes** (:func:`linear_episode_env`, :func:`linear_episode_rollout`): the policy
   is a bias-free linear controller ``Θ x`` with no Gaussian noise whose exploration is redrawn
   once per episode (SDE, the paper's ball-catching controller) or at every step (REX), so
   each step's action is a linear map known before the episode starts: ``Θ + σ̂ ⊙ ξ`` for the
   whole episode or ``Θ + σ̂ ⊙ ξ_t`` at step ``t`` (eqs. 17-19, :func:`episode_matrix`); an env
   that is a :class:`LinearEpisodeEnv` runs every world's whole episode under its maps, and
   ``loc``, ``scale`` and the likelihoods are computed for all steps at once.
2. **Tensor stepping** (:func:`tensor_step_env`, :func:`tensor_rollout`): the env is a
   :class:`TensorStepEnv` (dynamics as tensor functions) and the policy a ``TensorDictModule``
   followed by a :class:`TensorExplorer`; both are called on tensors at every step and one
   TensorDict is built at the end.
3. **TorchRL** ``env.rollout``: the reference, for everything else (other transforms, other
   policies, gymnasium envs).

What every path guarantees, for the same env, policy and random-stream states:

* **The same episodes as** ``env.rollout``: the fast paths draw from the explorer's streams (and
  the env's) in ``env.rollout``'s order, one ``ξ`` per step from the episode start. Tensor
  stepping agrees with ``env.rollout`` to float32 rounding (``torch.testing.assert_close``'s
  float32 tolerances; the random draws, hence ``sde_noise``, are identical), on the minimisation
  task for every schedule, MLP actors, squashing and Gaussian noise, and on the ball-catching
  worlds: ``tests/test_rollout.py::test_tensor_rollout_equals_env_rollout`` and
  ``::test_tensor_rollout_equals_env_rollout_on_the_ball_catching_worlds``. Linear episodes draw
  the same ``ξ`` (per episode or per step) bit for bit and leave the streams where tensor
  stepping leaves them (``::test_episode_matrix_is_theta_plus_sigma_noise_and_draws_like_act``);
  the env evaluates the maps in float64 where tensor stepping rounds to float32, so before the
  ball reaches the hand ``observation``, ``is_init``, ``done`` and ``truncated`` are identical
  and ``loc``, ``action_sample``, ``action``, ``scale``, the next observation and the reward
  agree to 1e-4, and mean episode rewards to 0.02 over 120 steps
  (``::test_linear_episode_rollout_gives_the_tensor_rollout_episodes``, SDE and REX, random and
  deterministic exploration).
* **The keys the estimators and the trainer read**, shaped ``[*batch, T]``: the explorer's
  ``feature_key`` (the observation), ``loc_key``, ``scale_key``, ``log_prob_key``,
  ``sample_key``, ``action_key``, ``is_init_key`` and, unless exploration is deterministic,
  ``noise_key``; under ``next``: ``observation``, ``reward``, ``done`` and ``truncated``. The
  fast paths write nothing else (``env.rollout`` adds, e.g., ``terminated``, ``step_count`` and
  the env's extra observations).
* **A fallback that is never wrong**: an env wrapped in a transform the fast paths do not
  reproduce, or a policy they do not know, goes to ``env.rollout``
  (``::test_envs_or_policies_it_cannot_reproduce_fall_back``,
  ``::test_linear_episode_path_needs_a_bias_free_linear_map_fixed_per_episode``,
  ``::test_linear_episode_path_needs_an_env_that_runs_linear_episodes``,
  ``tests/test_gym.py::test_collection_falls_back_to_env_rollout``), and ``fast=False`` forces it.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.envs import Compose, EnvBase, InitTracker, StepCounter, TensorDictPrimer, TransformedEnv

from sde_torchrl.modules.actors import BatchedLinear
from sde_torchrl.modules.distribution import gaussian_log_prob
from sde_torchrl.modules.exploration import deterministic_exploration
from sde_torchrl.utils.checks import positive_int
from sde_torchrl.utils.rng import RunStreams, draw_normal
from sde_torchrl.utils.shapes import align

#: Keys under which a :class:`TensorStepEnv`'s steps are written, TorchRL's defaults.
OBSERVATION_KEY, REWARD_KEY, DONE_KEY, TRUNCATED_KEY = "observation", "reward", "done", "truncated"

#: Transforms whose effect the fast paths reproduce (episode length, ``is_init``, the
#: explorer's primer). Any other transform must run, so it rules the fast paths out.
_REPRODUCED_TRANSFORMS = (Compose, StepCounter, InitTracker, TensorDictPrimer)

#: Exploration schedules under which a linear controller's maps are known before an episode
#: starts: redrawn per episode (SDE) or per step (REX).
LINEAR_SCHEDULES = ("episode", "step")


# ------------------------------------------------------------------------ what the paths need
# From Python 3.12 on, isinstance against a protocol sees only class and plain instance
# attributes, not an nn.Module's parameters or submodules: the protocols below list only the
# former, and the actor (a module whose network is a submodule) is checked by its class.
@runtime_checkable
class TensorStepEnv(Protocol):
    """An env stepped by tensor functions of the observation and the action (tensor stepping).

    The observation may be the whole state (:class:`~sde_torchrl.envs.MinimizeEnv`) or a view
    of a state kept inside the env (the ball-catching worlds): ``transition`` then reads its own.
    """

    batch_size: torch.Size

    def initial_state(self) -> torch.Tensor:
        """Resets every batch element; start observations ``[*batch, S]``."""

    def transition(self, x: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Next observations ``[*batch, S]`` and rewards ``[*batch, 1]``."""


@runtime_checkable
class LinearEpisodeEnv(TensorStepEnv, Protocol):
    """A :class:`TensorStepEnv` that also runs whole episodes of fixed linear controllers
    (:class:`~sde_torchrl.envs.BatchedBallCatchEnv`)."""

    def linear_episodes(self, matrices: torch.Tensor, steps: int, squash: bool = True) -> tuple[torch.Tensor, ...]:
        """Fresh episodes under ``u_t = M_t x_t``, ``M`` shaped ``[*batch, A, S]`` (one map per
        episode) or ``[*batch, steps, A, S]`` (one per step): ``(observations [*batch, steps + 1,
        S], pre-squash actions [*batch, steps, A], rewards [*batch, steps, 1])``."""


@runtime_checkable
class TensorExplorer(Protocol):
    """The exploration step on tensors and the keys of its outputs
    (:class:`~sde_torchrl.modules.exploration.StateDependentExplorer`)."""

    loc_key: str
    feature_key: str
    noise_key: str
    is_init_key: str
    sample_key: str
    scale_key: str
    action_key: str
    log_prob_key: str
    squash: bool

    def act(
        self, loc: torch.Tensor, features: torch.Tensor, noise: torch.Tensor | None = None,
        is_init: torch.Tensor | None = None, age: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """``(pre-squash action, noise, age)`` for one step."""

    def scale(self, features: torch.Tensor) -> torch.Tensor:
        """Per-action standard deviation (eq. 20)."""


@runtime_checkable
class EpisodeExplorer(TensorExplorer, Protocol):
    """A :class:`TensorExplorer` whose noise matrix ``ξ`` can be drawn for a whole episode."""

    schedule: str
    has_gaussian: bool
    streams: RunStreams | None
    run_dims: int
    action_dim: int
    feature_dim: int

    def noise_matrix(self, noise: torch.Tensor) -> torch.Tensor:
        """``Θ̂ = σ̂ ⊙ ξ`` (eq. 18)."""


# ------------------------------------------------------------------------------ the entry point
def collect_episodes(
    env: EnvBase, policy: TensorDictSequential, steps: int, *, fast: bool = True
) -> TensorDictBase:
    """Fresh whole episodes of ``steps`` steps, one per batch element of ``env``.

    Takes the fastest path that gives ``env.rollout``'s episodes (see the module docstring for
    what each path guarantees), else ``env.rollout(steps, policy, break_when_any_done=False)``.
    Runs under ``torch.no_grad()``; the exploration type in force (e.g.
    ``set_exploration_type(ExplorationType.DETERMINISTIC)``) applies.

    Args:
        env: the (batched) env, reset by the collection.
        policy: the policy, usually ``TensorDictSequential(actor, explorer)``.
        steps: episode length ``T``.
        fast: allow the fast paths; ``False`` forces ``env.rollout``.

    Returns:
        TensorDict shaped ``[*env.batch_size, steps]``.

    Raises:
        ArgumentError: if ``steps`` is not a positive integer.

    Examples:
        >>> from tensordict.nn import TensorDictSequential
        >>> from sde_torchrl import LinearActor, StateDependentExplorer, make_minimize_env
        >>> explorer = StateDependentExplorer(1, 1)
        >>> env = make_minimize_env(15, episodes=4).append_transform(explorer.make_tensordict_primer())
        >>> policy = TensorDictSequential(LinearActor(1, 1, init=-2.0), explorer)
        >>> collect_episodes(env, policy, 15).batch_size
        torch.Size([4, 15])
    """
    positive_int("steps", steps)
    with torch.no_grad():
        if fast:
            if (base := linear_episode_env(env, policy)) is not None:
                return linear_episode_rollout(base, policy, steps)
            if (base := tensor_step_env(env, policy)) is not None:
                return tensor_rollout(base, policy, steps)
        return env.rollout(steps, policy, break_when_any_done=False)


# -------------------------------------------------------------------------- tensor stepping
def tensor_step_env(env: EnvBase, policy: TensorDictSequential) -> TensorStepEnv | None:
    """The env to hand to :func:`tensor_rollout` for ``env`` and ``policy``, or ``None``.

    That needs an env that is a :class:`TensorStepEnv`, possibly wrapped only in transforms the
    fast paths reproduce, and a policy of two modules: a ``TensorDictModule`` whose ``module``
    maps the explorer's features to its ``loc``, then a :class:`TensorExplorer` whose features
    are the observation.
    """
    base = _untransformed(env)
    modules = list(policy.module)
    if not isinstance(base, TensorStepEnv) or len(modules) != 2:
        return None
    actor, explorer = modules
    supported = (isinstance(actor, TensorDictModule) and isinstance(explorer, TensorExplorer)
                 and explorer.feature_key == OBSERVATION_KEY
                 and actor.in_keys == [explorer.feature_key] and actor.out_keys == [explorer.loc_key])
    return base if supported else None


def tensor_rollout(env: TensorStepEnv, policy: TensorDictSequential, steps: int) -> TensorDict:
    """Collects one fresh episode of ``steps`` steps per batch element by tensor stepping.

    Args:
        env: a :class:`TensorStepEnv` (see :func:`tensor_step_env`).
        policy: ``TensorDictSequential(actor, explorer)``.
        steps: episode length ``T``.

    Returns:
        TensorDict ``[*batch, T]`` with the keys listed in the module docstring.
    """
    actor, explorer = policy.module
    x = env.initial_state()
    noise = age = None
    is_init = torch.ones(*env.batch_size, 1, dtype=torch.bool)
    observations, locs, samples, noises, next_observations, rewards = [], [], [], [], [], []
    for t in range(steps):
        loc = actor.module(x)
        sample, noise, age = explorer.act(loc, x, noise, is_init if t == 0 else ~is_init, age)
        x_next, reward = env.transition(x, torch.tanh(sample) if explorer.squash else sample)
        for column, value in ((observations, x), (locs, loc), (samples, sample), (noises, noise),
                              (next_observations, x_next), (rewards, reward)):
            column.append(value)
        x = x_next
    time_dim = len(env.batch_size)
    observation, loc, sample, next_observation, reward = (
        torch.stack(column, dim=time_dim) for column in (observations, locs, samples, next_observations, rewards)
    )
    noise = None if noises[0] is None else torch.stack(noises, dim=time_dim)
    return _episodes(explorer, observation, next_observation, loc, sample, reward, noise)


# -------------------------------------------------------------------------- linear episodes
def linear_episode_env(env: EnvBase, policy: TensorDictSequential) -> LinearEpisodeEnv | None:
    """The env to hand to :func:`linear_episode_rollout`, or ``None``.

    That needs what :func:`tensor_step_env` needs, an env that is a :class:`LinearEpisodeEnv`,
    an actor whose network is a bias-free :class:`~sde_torchrl.modules.actors.BatchedLinear` stacked like
    the explorer, and an :class:`EpisodeExplorer` with the ``episode`` (SDE, the paper's
    ball-catching controller) or ``step`` (REX) schedule and no Gaussian noise.
    """
    base = tensor_step_env(env, policy)
    if not isinstance(base, LinearEpisodeEnv):
        return None
    actor, explorer = policy.module
    linear = isinstance(actor.module, BatchedLinear) and actor.module.bias is None
    known_maps = (isinstance(explorer, EpisodeExplorer) and explorer.schedule in LINEAR_SCHEDULES
                  and not explorer.has_gaussian)
    return base if linear and known_maps and actor.module.run_dims == explorer.run_dims else None


def linear_episode_rollout(env: LinearEpisodeEnv, policy: TensorDictSequential, steps: int) -> TensorDict:
    """Fresh episodes as :func:`tensor_rollout` collects them, for a linear controller whose
    exploration is redrawn per episode (SDE) or per step (REX).

    The env runs each world's whole episode under its maps ``Θ + σ̂ ⊙ ξ`` (``Θ + σ̂ ⊙ ξ_t`` per
    step for REX, :func:`episode_matrix`), then the actor and explorer compute ``loc``,
    ``scale`` and log-likelihoods for all steps at once. Same random streams and keys as
    :func:`tensor_rollout`; the actions agree to float32 rounding (the env evaluates the maps in
    float64).

    Args:
        env: an env accepted by :func:`linear_episode_env`.
        policy: ``TensorDictSequential(LinearActor, StateDependentExplorer)``.
        steps: episode length ``T``.

    Returns:
        TensorDict ``[*batch, T]`` with the keys of :func:`tensor_rollout`.
    """
    actor, explorer = policy.module
    batch = env.batch_size
    matrices, noise = episode_matrix(explorer, actor.module.weight, batch, steps)
    observations, sample, reward = env.linear_episodes(matrices, steps, explorer.squash)
    observation = observations[..., :-1, :]
    if noise is not None and explorer.schedule == "episode":
        noise = noise.unsqueeze(len(batch)).expand(*batch, steps, *noise.shape[len(batch):])
    return _episodes(explorer, observation, observations[..., 1:, :], actor.module(observation), sample, reward,
                     noise)


def episode_matrix(
    explorer: EpisodeExplorer, weight: torch.Tensor, batch: torch.Size, steps: int
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The linear maps an episode of a linear controller ``Θ x`` follows: ``Θ + σ̂ ⊙ ξ`` for the
    whole episode (``episode`` schedule, SDE) or ``Θ + σ̂ ⊙ ξ_t`` at every step ``t`` (``step``
    schedule, REX) (eqs. 17-19), or ``Θ`` under deterministic exploration.

    Only without Gaussian noise, where these maps are all of the exploration. The explorer's
    random streams advance exactly as ``steps`` calls of its ``act`` from an episode start (one
    fresh draw per step; the ``episode`` schedule keeps the first), so both ways of collecting
    produce the same episodes.

    Args:
        explorer: the explorer, with the ``episode`` or ``step`` schedule and no Gaussian noise.
        weight: ``Θ``, ``[*runs, A, S]``.
        batch: batch shape of the episodes, runs first.
        steps: episode length.

    Returns:
        ``(M, ξ)``: ``M [*batch, A, S]`` and ``ξ [*batch, A, S]`` for the ``episode`` schedule,
        ``M [*batch, steps, A, S]`` and ``ξ [*batch, steps, A, S]`` for ``step``; under
        deterministic exploration ``(Θ [*batch, A, S], None)`` for both.

    Raises:
        ValueError: for another schedule or with Gaussian noise.

    Examples:
        >>> from sde_torchrl import StateDependentExplorer
        >>> explorer = StateDependentExplorer(4, 3)
        >>> matrix, noise = episode_matrix(explorer, torch.zeros(4, 3), torch.Size([5]), steps=10)
        >>> matrix.shape, noise.shape
        (torch.Size([5, 4, 3]), torch.Size([5, 4, 3]))
        >>> rex = StateDependentExplorer(4, 3, schedule="step")
        >>> episode_matrix(rex, torch.zeros(4, 3), torch.Size([5]), steps=10)[0].shape
        torch.Size([5, 10, 4, 3])
    """
    if explorer.schedule not in LINEAR_SCHEDULES or explorer.has_gaussian:
        raise ValueError("linear maps known in advance need schedule='episode' or 'step' and no Gaussian noise")
    shape = (*batch, explorer.action_dim, explorer.feature_dim)
    if deterministic_exploration():
        return align(weight, explorer.run_dims, len(batch)).expand(shape), None
    draws = (draw_normal(shape, explorer.streams) for _ in range(steps))
    if explorer.schedule == "step":
        noise = torch.stack(list(draws), dim=len(batch))
    else:
        noise = next(draws)
        for _ in draws:  # act's later draws, discarded by the episode schedule
            pass
    theta = align(weight, explorer.run_dims, noise.dim() - 2).expand(noise.shape)
    return theta + explorer.noise_matrix(noise), noise


# ------------------------------------------------------------------------------------ helpers
def _untransformed(env: EnvBase) -> EnvBase | None:
    """The base env under ``env``'s transforms, or ``None`` if one of them must run."""
    while isinstance(env, TransformedEnv):
        if not all(isinstance(t, _REPRODUCED_TRANSFORMS) for t in _flatten([env.transform])):
            return None
        env = env.base_env
    return env


def _flatten(transforms: list) -> list:
    flat = []
    for t in transforms:
        flat.extend(_flatten(list(t)) if isinstance(t, Compose) else [t])
    return flat


def _episodes(
    explorer: TensorExplorer, observation: torch.Tensor, next_observation: torch.Tensor,
    loc: torch.Tensor, sample: torch.Tensor, reward: torch.Tensor, noise: torch.Tensor | None,
) -> TensorDict:
    """The episode TensorDict ``[*batch, T]`` that ``env.rollout`` writes, from its step tensors."""
    batch = observation.shape[:-1]
    done = torch.zeros(*batch, 1, dtype=torch.bool)
    done[..., -1, :] = True
    first = torch.zeros(*batch, 1, dtype=torch.bool)
    first[..., 0, :] = True
    scale = explorer.scale(observation)  # eq. 20, once for all steps
    episodes = TensorDict({
        explorer.feature_key: observation,
        explorer.loc_key: loc,
        explorer.scale_key: scale,
        explorer.log_prob_key: gaussian_log_prob(sample, loc, scale),
        explorer.sample_key: sample,
        explorer.action_key: torch.tanh(sample) if explorer.squash else sample,
        explorer.is_init_key: first,
        "next": {OBSERVATION_KEY: next_observation, REWARD_KEY: reward, DONE_KEY: done, TRUNCATED_KEY: done.clone()},
    }, batch_size=batch)
    if noise is not None:
        episodes.set(explorer.noise_key, noise)
    return episodes
