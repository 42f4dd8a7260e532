"""Whole-episode collection without per-step TensorDict traffic, for tensor-stepping envs.

``EnvBase.rollout`` builds, transforms and stacks a TensorDict at every step. For an env whose
dynamics are plain tensor functions (``initial_state`` and ``transition``, as
:class:`~sde_torchrl.envs.MinimizeEnv` offers) the same episodes can be produced with a handful
of tensor operations per step: the actor's network and the explorer's :meth:`act` are called on
tensors, and one TensorDict ``[*batch, T]`` with the keys the estimators read is built at the end.
The random streams are consumed in the same order as ``env.rollout`` does, so both paths produce
the same first batch of episodes (tests check it).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.envs import Compose, EnvBase, InitTracker, StepCounter, TensorDictPrimer, TransformedEnv

from sde_torchrl.actors import BatchedLinear
from sde_torchrl.exploration import StateDependentExplorer, gaussian_log_prob


@runtime_checkable
class TensorStepEnv(Protocol):
    """An env stepped by tensor functions of the observation and the action.

    The observation may be the whole state (:class:`~sde_torchrl.envs.MinimizeEnv`) or a view
    of a state kept inside the env (the ball-catching worlds): ``transition`` then reads its own.
    """

    batch_size: torch.Size

    def initial_state(self) -> torch.Tensor:
        """Start states ``[*batch, S]``."""

    def transition(self, x: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Next states ``[*batch, S]`` and rewards ``[*batch, 1]``."""


#: Transforms whose effect :func:`tensor_rollout` reproduces (episode length, ``is_init``,
#: the explorer's primer). Any other transform must run, so it disables the tensor path.
_REPRODUCED_TRANSFORMS = (Compose, StepCounter, InitTracker, TensorDictPrimer)


def tensor_step_env(env: EnvBase, policy: TensorDictSequential) -> TensorStepEnv | None:
    """The env to hand to :func:`tensor_rollout` for ``env`` and ``policy``, or ``None``.

    That needs an env that is a :class:`TensorStepEnv`, possibly wrapped only in transforms the
    tensor path reproduces, and a policy made of one actor reading the observation followed by a
    :class:`StateDependentExplorer` whose features are the observation.
    """
    base = env
    while isinstance(base, TransformedEnv):
        transforms = list(base.transform) if isinstance(base.transform, Compose) else [base.transform]
        if not all(isinstance(t, _REPRODUCED_TRANSFORMS) for t in _flatten(transforms)):
            return None
        base = base.base_env
    modules = list(policy.module)
    if not isinstance(base, TensorStepEnv) or len(modules) != 2:
        return None
    actor, explorer = modules
    supported = (isinstance(actor, TensorDictModule) and actor.in_keys == ["observation"]
                 and isinstance(explorer, StateDependentExplorer)
                 and explorer.feature_key == "observation")
    return base if supported else None


def _flatten(transforms: list) -> list:
    flat = []
    for t in transforms:
        flat.extend(_flatten(list(t)) if isinstance(t, Compose) else [t])
    return flat


def tensor_rollout(env: TensorStepEnv, policy: TensorDictSequential, steps: int) -> TensorDict:
    """Collects one fresh episode of ``steps`` steps per batch element.

    Args:
        env: a :class:`TensorStepEnv` (see :func:`tensor_step_env`).
        policy: ``TensorDictSequential(actor, explorer)``.
        steps: episode length ``T``.

    Returns:
        TensorDict ``[*batch, T]`` with the policy's keys (``observation``, ``loc``, ``scale``,
        ``action``, ``action_sample``, ``action_log_prob``, ``sde_noise``), ``is_init`` and
        ``next`` (``observation``, ``reward``, ``done``, ``truncated``), as ``env.rollout``
        writes them.
    """
    actor, explorer = policy.module
    x = env.initial_state()
    noise = age = None
    is_init = torch.ones(*env.batch_size, 1, dtype=torch.bool)
    columns = {key: [] for key in ("observation", "loc", "action_sample", "sde_noise", "next_observation", "reward")}
    for t in range(steps):
        loc = actor.module(x)
        sample, noise, age = explorer.act(loc, x, noise, is_init if t == 0 else ~is_init, age)
        action = torch.tanh(sample) if explorer.squash else sample
        x_next, reward = env.transition(x, action)
        for key, value in (("observation", x), ("loc", loc), ("action_sample", sample), ("sde_noise", noise),
                           ("next_observation", x_next), ("reward", reward)):
            columns[key].append(value)
        x = x_next
    stacked = {key: torch.stack(values, dim=len(env.batch_size)) for key, values in columns.items()
               if values[0] is not None}
    return _episodes(explorer, stacked.pop("observation"), stacked.pop("next_observation"), stacked.pop("loc"),
                     stacked.pop("action_sample"), stacked.pop("reward"), stacked.get("sde_noise"))


def linear_episode_env(env: EnvBase, policy: TensorDictSequential) -> TensorStepEnv | None:
    """The env to hand to :func:`linear_episode_rollout`, or ``None``.

    That needs what :func:`tensor_step_env` needs, an env that runs whole episodes of fixed
    linear controllers (``linear_episodes``, as :class:`~sde_torchrl.envs.BatchedBallCatchEnv`
    does), a bias-free :class:`~sde_torchrl.actors.LinearActor` and an explorer with the
    ``episode`` schedule and no Gaussian noise (the paper's ball-catching controller).
    """
    base = tensor_step_env(env, policy)
    if base is None or not hasattr(base, "linear_episodes"):
        return None
    actor, explorer = policy.module
    linear = isinstance(actor.module, BatchedLinear) and actor.module.bias is None
    return base if linear and explorer.schedule == "episode" and not explorer.has_gaussian else None


def linear_episode_rollout(env: TensorStepEnv, policy: TensorDictSequential, steps: int) -> TensorDict:
    """Fresh episodes as :func:`tensor_rollout` collects them, for a linear controller whose
    exploration is fixed per episode: the env runs each world's whole episode under its map
    ``Θ + σ̂ ⊙ ξ`` (:meth:`~sde_torchrl.exploration.StateDependentExplorer.episode_matrix`),
    then the actor and explorer compute ``loc``, ``scale`` and log-likelihoods for all steps
    at once. Same random streams and keys as :func:`tensor_rollout`; the actions agree to
    float32 rounding (the env evaluates the map in float64).

    Args:
        env: an env accepted by :func:`linear_episode_env`.
        policy: ``TensorDictSequential(LinearActor, StateDependentExplorer)``.
        steps: episode length ``T``.

    Returns:
        TensorDict ``[*batch, T]`` with the keys of :func:`tensor_rollout`.
    """
    actor, explorer = policy.module
    batch = env.batch_size
    matrices, noise = explorer.episode_matrix(actor.module.weight, batch, steps)
    observations, sample, reward = env.linear_episodes(matrices, steps, explorer.squash)
    observation = observations[..., :-1, :]
    if noise is not None:
        noise = noise.unsqueeze(len(batch)).expand(*batch, steps, *noise.shape[len(batch):])
    return _episodes(explorer, observation, observations[..., 1:, :], actor.module(observation), sample, reward,
                     noise)


def _episodes(
    explorer: StateDependentExplorer, observation: torch.Tensor, next_observation: torch.Tensor,
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
        "observation": observation,
        "loc": loc,
        "scale": scale,
        "action_log_prob": gaussian_log_prob(sample, loc, scale),
        "action_sample": sample,
        "action": torch.tanh(sample) if explorer.squash else sample,
        "is_init": first,
        "next": {"observation": next_observation, "reward": reward, "done": done, "truncated": done.clone()},
    }, batch_size=batch)
    if noise is not None:
        episodes.set("sde_noise", noise)
    return episodes
