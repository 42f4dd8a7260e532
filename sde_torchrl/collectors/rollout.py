"""Whole-episode collection: :func:`collect_episodes`, the one entry point, and the paths it picks.

Every update needs ``N`` fresh whole episodes of ``T`` steps. ``env.rollout(T, policy,
break_when_any_done=False)`` gives them for any env and policy but builds a TensorDict at every
step; where the env and the policy allow it, the same episodes come from a faster path.
:func:`collect_episodes` takes the first path whose eligibility function accepts both:

1. **Linear episodes** (:func:`linear_episode_env`, :func:`linear_episode_rollout`): a bias-free
   linear controller whose exploration is redrawn per episode (SDE) or per step (REX), so every
   action is a map known in advance, ``Θ + σ̂ ⊙ ξ`` (eqs. 17-19, :func:`episode_matrix`).
2. **Tensor stepping** (:func:`tensor_step_env`, :func:`tensor_rollout`): a :class:`TensorStepEnv`
   and an :class:`~sde_torchrl.modules.sde_actor.SDEActor`, called on tensors at every step.
3. **Parameter-exploring episodes** (:func:`parameter_step_env`, :func:`parameter_rollout`): a
   :class:`TensorStepEnv` and PGPE's policy (:mod:`sde_torchrl.modules.pgpe`).
4. **TorchRL** ``env.rollout``: the reference, for everything else.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.envs import Compose, EnvBase, InitTracker, StepCounter, TensorDictPrimer, TransformedEnv

from sde_torchrl.modules.actors import BatchedLinear
from sde_torchrl.modules.distribution import TanhSDENormal, noise_matrix, sde_sample, squash, tanh_bounds
from sde_torchrl.modules.distribution import explore as explore_with
from sde_torchrl.modules.noise import SDENoisePrimer, deterministic_exploration
from sde_torchrl.modules.pgpe import ParameterExplorer
from sde_torchrl.modules.sde import SDEParams
from sde_torchrl.modules.sde_actor import SDEActor
from sde_torchrl.utils.checks import positive_int
from sde_torchrl.utils.shapes import align

#: Keys under which a :class:`TensorStepEnv`'s steps are written, TorchRL's defaults.
OBSERVATION_KEY, REWARD_KEY, DONE_KEY, TRUNCATED_KEY, IS_INIT_KEY = (
    "observation", "reward", "done", "truncated", "is_init")

#: Transforms whose effect the fast paths reproduce (episode length, ``is_init``, the noise
#: primer). Any other transform must run, so it rules the fast paths out.
_REPRODUCED_TRANSFORMS = (Compose, StepCounter, InitTracker, TensorDictPrimer)

#: Exploration schedules under which a linear controller's maps are known before an episode
#: starts: redrawn per episode (SDE) or per step (REX).
LINEAR_SCHEDULES = ("episode", "step")


# ------------------------------------------------------------------------ what the paths need
# From Python 3.12 on, isinstance against a protocol sees only class and plain instance
# attributes, not an nn.Module's parameters or submodules: the protocols below list only the
# former, and the policy is checked by its class.
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
    (:class:`~sde_torchrl.envs.BatchedBallCatchEnv`, :class:`~sde_torchrl.envs.MinimizeEnv`)."""

    def linear_episodes(self, matrices: torch.Tensor, steps: int, squash: bool = True) -> tuple[torch.Tensor, ...]:
        """Fresh episodes under ``u_t = M_t x_t``, ``M`` shaped ``[*batch, A, S]`` (one map per
        episode) or ``[*batch, steps, A, S]`` (one per step): ``(observations [*batch, steps + 1,
        S], pre-squash actions [*batch, steps, A], rewards [*batch, steps, 1])``."""


# ------------------------------------------------------------------------------ the entry point
def collect_episodes(
    env: EnvBase, policy: SDEActor | TensorDictSequential, steps: int, *, fast: bool = True
) -> TensorDictBase:
    """Fresh whole episodes of ``steps`` steps, one per batch element of ``env``.

    Takes the fastest path that gives ``env.rollout``'s episodes (the module docstring lists
    them), else ``env.rollout(steps, policy, break_when_any_done=False)``. Runs under
    ``torch.no_grad()``, a fast path under ``torch.inference_mode()`` (its episodes cloned out of
    it); the exploration type in force (e.g. ``set_exploration_type(ExplorationType.DETERMINISTIC)``)
    applies. For the same env, policy and random-stream states every path guarantees:

    * **The same episodes as** ``env.rollout``: the fast paths draw through the env's noise primer
      (:meth:`~sde_torchrl.modules.noise.SDENoisePrimer.start` and ``advance``), from its streams
      (and the env's) in ``env.rollout``'s order, one ``ξ`` per step from the episode start.
      Tensor stepping agrees to float32 rounding, its random draws (hence ``sde_noise``)
      identical. Linear episodes draw the same ``ξ`` bit for bit; the ball-catching worlds
      evaluate the maps in float64, so before the ball reaches the hand the observations and
      flags are identical and ``loc``, the actions, the next observation and the reward agree
      to 1e-4 (mean episode rewards to 0.02 over 120 steps); on the minimisation task
      ``Θ x + Θ̂ x`` becomes ``(Θ + Θ̂) x``, equal to float32 rounding. Parameter-exploring
      episodes draw PGPE's ``ξ`` from the explorer's streams and write every key bit for bit
      as ``env.rollout`` does (the env primer's draws, which the explorer replaces at every
      episode start, are not made).
    * **The keys the estimators and the trainer read**, shaped ``[*batch, T]``: the observation
      (the features), the ``SDEParams``' ``loc_key``, the policy's ``action_key``,
      ``log_prob_key`` and (squashed) ``sample_key``, ``is_init`` and, unless exploration is
      deterministic, the noise (``noise_key``, and ``gaussian_noise_key`` with eq. 22's part);
      under ``next``: ``observation``, ``reward``, ``done`` and ``truncated``; for PGPE, the
      explorer's keys (``loc``, ``action``, ``action_sample``, ``pgpe_parameters`` and, unless
      exploration is deterministic, ``pgpe_noise``) in place of the SDE policy's. The fast paths
      write nothing else (``env.rollout`` adds, e.g., ``terminated``, ``step_count``, ``σ̂`` and
      the env's extra observations).
    * **A fallback that is never wrong**: an env wrapped in a transform the fast paths do not
      reproduce, or a policy they do not know, goes to ``env.rollout``; ``fast=False`` forces it.

    Args:
        env: the (batched) env, reset by the collection.
        policy: the policy, usually :func:`~sde_torchrl.modules.sde_actor.make_sde_actor`'s, or
            PGPE's ``TensorDictSequential(actor, ParameterExplorer(actor))``.
        steps: episode length ``T``.
        fast: allow the fast paths; ``False`` forces ``env.rollout``.

    Returns:
        TensorDict shaped ``[*env.batch_size, steps]``.

    Raises:
        ArgumentError: if ``steps`` is not a positive integer.

    Examples:
        >>> from sde_torchrl import LinearActor, SDEParams, make_minimize_env, make_sde_actor
        >>> sde = SDEParams(1, 1)
        >>> env = make_minimize_env(15, episodes=4).append_transform(sde.make_tensordict_primer())
        >>> policy = make_sde_actor(LinearActor(1, 1, init=-2.0), sde)
        >>> collect_episodes(env, policy, 15).batch_size
        torch.Size([4, 15])
    """
    positive_int("steps", steps)
    with torch.no_grad():
        if fast:
            if (base := linear_episode_env(env, policy)) is not None:
                return _without_autograd(linear_episode_rollout, base, policy, steps, noise_primer(env))
            if (base := tensor_step_env(env, policy)) is not None:
                return _without_autograd(tensor_rollout, base, policy, steps, noise_primer(env))
            if (base := parameter_step_env(env, policy)) is not None:
                return _without_autograd(parameter_rollout, base, policy, steps)
        return env.rollout(steps, policy, break_when_any_done=False)


def _without_autograd(collect, *args) -> TensorDict:
    """``collect(*args)`` under ``torch.inference_mode()``, which spares its many small per-step
    ops autograd's bookkeeping, its episodes cloned out of it: the update's autograd reads them."""
    with torch.inference_mode():
        episodes = collect(*args)
    return episodes.clone()


# -------------------------------------------------------------------------- tensor stepping
def tensor_step_env(env: EnvBase, policy: object) -> TensorStepEnv | None:
    """The env to hand to :func:`tensor_rollout` for ``env`` and ``policy``, or ``None``.

    That needs an env that is a :class:`TensorStepEnv`, possibly wrapped only in transforms the
    fast paths reproduce, among them one :class:`~sde_torchrl.modules.noise.SDENoisePrimer` for
    the policy's noise (:func:`noise_primer`), and an
    :class:`~sde_torchrl.modules.sde_actor.SDEActor` over two modules: a ``TensorDictModule``
    whose ``module`` maps the observation to the ``loc``, then ``SDEParams`` whose features are
    the observation.
    """
    base = _untransformed(env)
    if not isinstance(base, TensorStepEnv) or not isinstance(policy, SDEActor):
        return None
    if len(policy.actor_modules) != 1:
        return None
    (actor,), sde = policy.actor_modules, policy.sde
    primer = noise_primer(env)
    supported = (isinstance(actor, TensorDictModule) and isinstance(sde, SDEParams)
                 and sde.feature_key == OBSERVATION_KEY
                 and actor.in_keys == [sde.feature_key] and actor.out_keys == [sde.loc_key]
                 and primer is not None and primer.noise_key == sde.noise_key
                 and primer.gaussian == sde.has_gaussian
                 and (not sde.has_gaussian or primer.gaussian_noise_key == sde.gaussian_noise_key))
    return base if supported else None


def noise_primer(env: EnvBase) -> SDENoisePrimer | None:
    """The env's one :class:`~sde_torchrl.modules.noise.SDENoisePrimer` among its transforms, or ``None``."""
    primers = []
    while isinstance(env, TransformedEnv):
        primers += [t for t in _flatten([env.transform]) if isinstance(t, SDENoisePrimer)]
        env = env.base_env
    return primers[0] if len(primers) == 1 else None


def tensor_rollout(env: TensorStepEnv, policy: SDEActor, steps: int, primer: SDENoisePrimer) -> TensorDict:
    """Collects one fresh episode of ``steps`` steps per batch element by tensor stepping.

    Args:
        env: a :class:`TensorStepEnv` (see :func:`tensor_step_env`).
        policy: the :class:`~sde_torchrl.modules.sde_actor.SDEActor`.
        steps: episode length ``T``.
        primer: the env's noise primer (:func:`noise_primer`).

    Returns:
        TensorDict ``[*batch, T]`` with the keys listed in :func:`collect_episodes`.
    """
    (actor,), sde = policy.actor_modules, policy.sde
    batch = env.batch_size
    x = env.initial_state()
    explore = not deterministic_exploration()
    # every step's ξ in one draw where the primer can (the same numbers): Θ̂ then comes in one product
    all_noise = primer.episode_noise(batch, steps, x.device) if explore else None
    noise, gaussian, age = primer.start(batch, x.device) if explore and all_noise is None else (None, None, None)
    sigma = align(sde.sde_sigma, sde.run_dims, len(batch))
    gaussian_scale = sde.gaussian_scale(len(batch))
    mid, half = tanh_bounds(*_bounds(policy, x.device)) if policy.squash else (None, None)  # once, not per step
    observations, locs, samples, noises, gaussians, next_observations, rewards = [], [], [], [], [], [], []
    for t in range(steps):
        loc = actor.module(x)
        if t == 0:  # the policy's dtype, known from its first output: cast σ̂ (and σ_gauss) once
            sigma = sigma.to(loc.dtype)
            gaussian_scale = None if gaussian_scale is None else gaussian_scale.to(loc.dtype)
            exploration = None if all_noise is None else noise_matrix(sigma, all_noise)  # Θ̂ of every step
        if exploration is not None:
            sample = explore_with(loc, exploration[t], x.to(loc.dtype))
        else:
            sample = sde_sample(loc, sigma, noise, x.to(loc.dtype), gaussian_scale, gaussian) if explore else loc
        x_next, reward = env.transition(x, squash(sample, mid, half) if policy.squash else sample)
        for column, value in ((observations, x), (locs, loc), (samples, sample), (noises, noise),
                              (gaussians, gaussian), (next_observations, x_next), (rewards, reward)):
            column.append(value)
        x = x_next
        if noise is not None and t < steps - 1:  # after the last step every episode ends: the reset draws
            noise, gaussian, age = primer.advance(noise, gaussian, age)
    time_dim = len(batch)
    observation, loc, sample, next_observation, reward = (
        torch.stack(column, dim=time_dim) for column in (observations, locs, samples, next_observations, rewards)
    )
    if all_noise is not None:
        stacked_noise = all_noise.movedim(0, time_dim).contiguous()
    else:
        stacked_noise = None if noises[0] is None else torch.stack(noises, dim=time_dim)
    stacked_gaussian = None if gaussians[0] is None else torch.stack(gaussians, dim=time_dim)
    return _episodes(policy, observation, next_observation, loc, sample, reward, stacked_noise, stacked_gaussian)


# -------------------------------------------------------------------------- linear episodes
def linear_episode_env(env: EnvBase, policy: object) -> LinearEpisodeEnv | None:
    """The env to hand to :func:`linear_episode_rollout`, or ``None``.

    That needs what :func:`tensor_step_env` needs, an env that is a :class:`LinearEpisodeEnv`,
    an actor whose network is a bias-free :class:`~sde_torchrl.modules.actors.BatchedLinear`
    stacked like ``SDEParams``, the ``episode`` (SDE, the paper's ball-catching controller) or
    ``step`` (REX) schedule, no Gaussian noise, and, squashed, the bounds ``[-1, 1]`` (the env
    applies ``tanh``).
    """
    base = tensor_step_env(env, policy)
    if not isinstance(base, LinearEpisodeEnv):
        return None
    (actor,), sde = policy.actor_modules, policy.sde
    linear = isinstance(actor.module, BatchedLinear) and actor.module.bias is None
    known_maps = noise_primer(env).schedule in LINEAR_SCHEDULES and not sde.has_gaussian
    unit_bounds = not policy.squash or all(bool((bound.abs() == 1).all()) for bound in _bounds(policy))
    return base if linear and known_maps and unit_bounds and actor.module.run_dims == sde.run_dims else None


def linear_episode_rollout(
    env: LinearEpisodeEnv, policy: SDEActor, steps: int, primer: SDENoisePrimer
) -> TensorDict:
    """Fresh episodes as :func:`tensor_rollout` collects them, for a linear controller whose
    exploration is redrawn per episode (SDE) or per step (REX).

    The env runs each world's whole episode under its maps ``Θ + σ̂ ⊙ ξ`` (``Θ + σ̂ ⊙ ξ_t`` per
    step for REX, :func:`episode_matrix`), then the actor computes ``loc`` and the
    log-likelihoods for all steps at once. Same random streams and keys as
    :func:`tensor_rollout`; the actions agree to float32 rounding (the env evaluates the maps in
    float64).

    Args:
        env: an env accepted by :func:`linear_episode_env`.
        policy: the :class:`~sde_torchrl.modules.sde_actor.SDEActor` of a ``LinearActor``.
        steps: episode length ``T``.
        primer: the env's noise primer (:func:`noise_primer`).

    Returns:
        TensorDict ``[*batch, T]`` with the keys of :func:`tensor_rollout`.
    """
    (actor,), sde = policy.actor_modules, policy.sde
    batch = env.batch_size
    matrices, noise = episode_matrix(primer, sde, actor.module.weight, batch, steps)
    observations, sample, reward = env.linear_episodes(matrices, steps, policy.squash)
    observation = observations[..., :-1, :]
    if noise is not None and primer.schedule == "episode":
        noise = noise.unsqueeze(len(batch)).expand(*batch, steps, *noise.shape[len(batch):])
    return _episodes(policy, observation, observations[..., 1:, :], actor.module(observation), sample, reward,
                     noise, None)


def episode_matrix(
    primer: SDENoisePrimer, sde: SDEParams, weight: torch.Tensor, batch: torch.Size, steps: int
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The linear maps an episode of a linear controller ``Θ x`` follows: ``Θ + σ̂ ⊙ ξ`` for the
    whole episode (``episode`` schedule, SDE) or ``Θ + σ̂ ⊙ ξ_t`` at every step ``t`` (``step``
    schedule, REX) (eqs. 17-19), or ``Θ`` under deterministic exploration.

    Only without Gaussian noise, where these maps are all of the exploration. The noise comes
    from the primer as an episode of ``steps`` steps draws it (:meth:`SDENoisePrimer.start
    <sde_torchrl.modules.noise.SDENoisePrimer.start>`, then ``advance`` after each step but the
    last), so both ways of collecting produce the same episodes and leave the streams alike.

    Args:
        primer: the env's noise primer, with the ``episode`` or ``step`` schedule.
        sde: the policy's ``SDEParams``, without Gaussian noise.
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
        >>> from sde_torchrl import SDEParams
        >>> sde = SDEParams(4, 3)
        >>> matrix, noise = episode_matrix(sde.make_tensordict_primer(), sde, torch.zeros(4, 3), torch.Size([5]), 10)
        >>> matrix.shape, noise.shape
        (torch.Size([5, 4, 3]), torch.Size([5, 4, 3]))
        >>> rex = SDEParams(4, 3, schedule="step")
        >>> episode_matrix(rex.make_tensordict_primer(), rex, torch.zeros(4, 3), torch.Size([5]), 10)[0].shape
        torch.Size([5, 10, 4, 3])
    """
    if primer.schedule not in LINEAR_SCHEDULES or sde.has_gaussian:
        raise ValueError("linear maps known in advance need schedule='episode' or 'step' and no Gaussian noise")
    if deterministic_exploration():
        return align(weight, sde.run_dims, len(batch)).expand(*batch, sde.action_dim, sde.feature_dim), None
    every_step = primer.episode_noise(batch, steps, weight.device)  # one draw, where it gives the same numbers
    if every_step is None:
        noise, gaussian, age = primer.start(batch, weight.device)
        noises = [noise]
        for _ in range(steps - 1):
            noise, gaussian, age = primer.advance(noise, gaussian, age)
            noises.append(noise)
        every_step = torch.stack(noises)
    noise = every_step.movedim(0, len(batch)).contiguous() if primer.schedule == "step" else every_step[0]
    theta = align(weight, sde.run_dims, noise.dim() - 2).expand(noise.shape)
    return theta + align(sde.sde_sigma, sde.run_dims, noise.dim() - 2) * noise, noise


# -------------------------------------------------------------- parameter-exploring episodes
def parameter_step_env(env: EnvBase, policy: object) -> TensorStepEnv | None:
    """The env to hand to :func:`parameter_rollout` for ``env`` and ``policy``, or ``None``.

    That needs an env that is a :class:`TensorStepEnv`, possibly wrapped only in transforms the
    fast paths reproduce, among them an ``InitTracker`` (where ``is_init`` is set, the explorer
    draws the episode's parameters), and PGPE's policy ``TensorDictSequential(actor,
    ParameterExplorer(actor))`` whose actor is a ``TensorDictModule`` mapping the observation
    to the explorer's ``loc`` and whose explorer draws from its per-run ``streams`` (from
    torch's global generator, its draws would follow those of the env's random primer, which
    this path does not make).
    """
    base = _untransformed(env)
    if not isinstance(base, TensorStepEnv) or not isinstance(policy, TensorDictSequential):
        return None
    modules = list(policy.module)
    if len(modules) != 2 or not isinstance(modules[1], ParameterExplorer):
        return None
    actor, explorer = modules
    supported = (isinstance(actor, TensorDictModule) and explorer.network is actor.module
                 and actor.in_keys == explorer.actor_in_keys == [OBSERVATION_KEY]
                 and actor.out_keys == [explorer.loc_key] and explorer.streams is not None
                 and _has_transform(env, InitTracker))
    return base if supported else None


def parameter_rollout(env: TensorStepEnv, policy: TensorDictSequential, steps: int) -> TensorDict:
    """Collects one fresh episode of ``steps`` steps per batch element under PGPE's exploration.

    Each episode's parameters ``θ = μ + σ ⊙ ξ`` are drawn before its first step
    (:meth:`~sde_torchrl.modules.pgpe.ParameterExplorer.next_noise`, symmetric pairs included)
    and held while it runs (Sehnke et al. 2010, section 2): ``u_t = f(x_t; θ)``, squashed by
    ``tanh`` if the explorer squashes; under deterministic exploration nothing is drawn and
    ``u_t = f(x_t; μ)``.

    Args:
        env: a :class:`TensorStepEnv` (see :func:`parameter_step_env`).
        policy: ``TensorDictSequential(actor, ParameterExplorer(actor))``.
        steps: episode length ``T``.

    Returns:
        TensorDict ``[*batch, T]`` with the keys listed in :func:`collect_episodes`.

    Examples:
        >>> from tensordict.nn import TensorDictSequential
        >>> from sde_torchrl import LinearActor, make_minimize_env
        >>> from sde_torchrl.modules.pgpe import ParameterExplorer
        >>> from sde_torchrl.utils.rng import RunStreams
        >>> actor = LinearActor(1, 1, bias=False, init=-2.0, runs=3)
        >>> explorer = ParameterExplorer(actor, runs=3)
        >>> explorer.streams = RunStreams(seed=0, runs=3, stream="explore")
        >>> policy = TensorDictSequential(actor, explorer)
        >>> env = make_minimize_env(15, episodes=4, runs=3)
        >>> episodes = parameter_rollout(parameter_step_env(env, policy), policy, 15)
        >>> episodes.batch_size, episodes["pgpe_parameters"].shape
        (torch.Size([3, 4, 15]), torch.Size([3, 4, 15, 1]))
    """
    actor, explorer = policy.module
    batch = env.batch_size
    x = env.initial_state()
    if deterministic_exploration():  # nothing drawn: the controller at μ, which is the actor
        noise = None
        parameters = align(explorer.mean(), explorer.run_dims, len(batch)).expand(*batch, explorer.num_parameters)
    else:
        noise = explorer.next_noise(None, None, batch)
        parameters = explorer.perturbed(noise)
        controller = explorer.episode_controller(parameters)
    observations, locs, samples, next_observations, rewards = [], [], [], [], []
    for _ in range(steps):
        loc = actor.module(x)
        sample = loc if noise is None else controller(x)
        x_next, reward = env.transition(x, torch.tanh(sample) if explorer.squash else sample)
        for column, value in ((observations, x), (locs, loc), (samples, sample), (next_observations, x_next),
                              (rewards, reward)):
            column.append(value)
        x = x_next
    time_dim = len(batch)
    observation, loc, sample, next_observation, reward = (
        torch.stack(column, dim=time_dim) for column in (observations, locs, samples, next_observations, rewards)
    )
    episodes = _step_entries(observation, next_observation, reward)
    episodes.update({
        explorer.loc_key: loc, explorer.sample_key: sample,
        explorer.action_key: torch.tanh(sample) if explorer.squash else sample,
        explorer.parameters_key: _held(parameters, time_dim, steps),
    })
    if noise is not None:
        episodes.set(explorer.noise_key, _held(noise, time_dim, steps))
    return episodes


def _held(value: torch.Tensor, time_dim: int, steps: int) -> torch.Tensor:
    """A per-episode ``value`` ``[*batch, K]`` at every step, ``[*batch, steps, K]`` (a view)."""
    return value.unsqueeze(time_dim).expand(*value.shape[:time_dim], steps, *value.shape[time_dim:])


# ------------------------------------------------------------------------------------ helpers
def _untransformed(env: EnvBase) -> EnvBase | None:
    """The base env under ``env``'s transforms, or ``None`` if one of them must run."""
    while isinstance(env, TransformedEnv):
        if not all(isinstance(t, _REPRODUCED_TRANSFORMS) for t in _flatten([env.transform])):
            return None
        env = env.base_env
    return env


def _has_transform(env: EnvBase, kind: type) -> bool:
    """Whether one of ``env``'s transforms is a ``kind``."""
    found = []
    while isinstance(env, TransformedEnv):
        found += [t for t in _flatten([env.transform]) if isinstance(t, kind)]
        env = env.base_env
    return bool(found)


def _flatten(transforms: list) -> list:
    flat = []
    for t in transforms:
        flat.extend(_flatten(list(t)) if isinstance(t, Compose) else [t])
    return flat


def _bounds(policy: SDEActor, device: torch.device | str | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """The squashed policy's ``(low, high)``, on ``device`` if given (the data's)."""
    low, high = policy.bounds
    return (low, high) if device is None else (low.to(device), high.to(device))


def _episodes(
    policy: SDEActor, observation: torch.Tensor, next_observation: torch.Tensor, loc: torch.Tensor,
    sample: torch.Tensor, reward: torch.Tensor, noise: torch.Tensor | None, gaussian: torch.Tensor | None,
) -> TensorDict:
    """The episode TensorDict ``[*batch, T]`` that ``env.rollout`` writes, from its step tensors."""
    sde = policy.sde
    batch, device = observation.shape[:-1], observation.device
    features = observation.to(loc.dtype)
    sigma = align(sde.sde_sigma, sde.run_dims, len(batch)).to(loc.dtype)
    gaussian_scale = sde.gaussian_scale(len(batch))
    if policy.squash:
        low, high = _bounds(policy, device)
        dist = TanhSDENormal(loc, sigma, features, gaussian_scale=gaussian_scale, low=low, high=high)
        action = dist.squash(sample)
    else:
        dist, action = policy.module[-1].distribution_class(loc, sigma, features, gaussian_scale=gaussian_scale), sample
    episodes = _step_entries(observation, next_observation, reward)
    episodes.update({
        sde.loc_key: loc,
        policy.action_key: action,
        policy.log_prob_key: dist.log_prob(action),  # eqs. 13, 20, once for all steps
    })
    if policy.squash:
        episodes.set(policy.sample_key, sample)
    if noise is not None:
        episodes.set(sde.noise_key, noise)
    if gaussian is not None:
        episodes.set(sde.gaussian_noise_key, gaussian)
    return episodes


def _step_entries(observation: torch.Tensor, next_observation: torch.Tensor, reward: torch.Tensor) -> TensorDict:
    """The entries of ``env.rollout``'s episodes ``[*batch, T]`` that are the env's: the observations,
    ``is_init`` at the first step, and under ``next`` the observations, rewards, and ``done`` and
    ``truncated`` at the last step."""
    batch, device = observation.shape[:-1], observation.device
    done = torch.zeros(*batch, 1, dtype=torch.bool, device=device)
    done[..., -1, :] = True
    first = torch.zeros(*batch, 1, dtype=torch.bool, device=device)
    first[..., 0, :] = True
    return TensorDict({
        OBSERVATION_KEY: observation,
        IS_INIT_KEY: first,
        "next": {OBSERVATION_KEY: next_observation, REWARD_KEY: reward, DONE_KEY: done, TRUNCATED_KEY: done.clone()},
    }, batch_size=batch)  # no device=: it would move a stray CPU entry instead of showing it
