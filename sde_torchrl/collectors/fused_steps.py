"""Step collection on tensors: the steps of ``env.step_and_maybe_reset(policy(td))`` without
TorchRL's per-step tensordict machinery, for the envs and policies whose parts it knows.

:class:`~sde_torchrl.collectors.steps.StepCollector` takes this path for a
:class:`~sde_torchrl.envs.vector.GymVectorEnv` wrapped in no transforms but ``RewardSum``,
:class:`~sde_torchrl.envs.normalize.RunningNormalize` and
:class:`~sde_torchrl.modules.noise.SDENoisePrimer`, in that order (what the PPO and A2C builders
make). Each step calls the same parts the reference path calls through TorchRL, on tensors: the
gymnasium envs (:meth:`~sde_torchrl.envs.vector.GymVectorEnv.step_arrays`, ``reset_arrays``),
the episode sum, the normaliser (``observe``, ``normalize``), the noise schedule (``step_noise``,
``reset_noise``) and the policy, which an :class:`~sde_torchrl.modules.sde_actor.SDEActor`
(squashed or not) over a :class:`~sde_torchrl.modules.actors.LatentMLPActor` and SAC's
tanh-squashed Gaussian compute on tensors (:func:`tensor_policy`), any other policy on a small
tensordict. The rollout and the carried
state are assembled once per rollout, with the same keys and numbers as the reference path.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictSequential
from tensordict.utils import NestedKey, expand_as_right
from torchrl.envs import Compose, EnvBase, RewardSum, TransformedEnv
from torchrl.modules import ProbabilisticActor, TanhNormal
from torchrl.modules.distributions.utils import sample_and_log_prob

from sde_torchrl.envs.normalize import RunningNormalize
from sde_torchrl.envs.vector import GymVectorEnv
from sde_torchrl.modules.actors import LatentMLPActor
from sde_torchrl.modules.distribution import sde_sample_and_log_prob, tanh_bounds, tanh_sde_sample_and_log_prob
from sde_torchrl.modules.noise import SDENoisePrimer
from sde_torchrl.modules.sac_actor import GaussianHeads
from sde_torchrl.modules.sde_actor import SDEActor

#: A policy on tensors: the carried entries in, the entries it writes out.
TensorPolicy = Callable[[dict[NestedKey, torch.Tensor]], dict[NestedKey, torch.Tensor]]
#: The flags every step writes.
FLAGS = ("done", "terminated", "truncated")
#: The transforms this path reproduces, in the order it applies them.
_KNOWN = (RewardSum, RunningNormalize, SDENoisePrimer)


@dataclass(frozen=True)
class FusedEnv:
    """The parts of an env that :func:`fused_rollout` steps: the gymnasium envs, and the
    episode sum (its key), the normaliser and the noise primer where the env has them."""

    base: GymVectorEnv
    episode_key: str | None
    normalizer: RunningNormalize | None
    primer: SDENoisePrimer | None


def fused_env(env: EnvBase) -> FusedEnv | None:
    """``env``'s parts for :func:`fused_rollout`, or ``None`` where the path does not apply (another
    base env, another transform, another order, a sum of other keys)."""
    transforms: list = []
    base = env
    while isinstance(base, TransformedEnv):
        transforms = [*_flatten(base.transform), *transforms]
        base = base.base_env
    if not isinstance(base, GymVectorEnv):
        return None
    kinds = [next((i for i, kind in enumerate(_KNOWN) if type(t) is kind), None) for t in transforms]
    if None in kinds or kinds != sorted(set(kinds)):
        return None
    parts = dict(zip(kinds, transforms, strict=True))
    reward_sum = parts.get(0)
    if reward_sum is not None and (list(reward_sum.in_keys) != ["reward"] or len(reward_sum.out_keys) != 1
                                   or not isinstance(reward_sum.out_keys[0], str)):
        return None
    return FusedEnv(base, None if reward_sum is None else reward_sum.out_keys[0], parts.get(1), parts.get(2))


def tensor_policy(policy: object) -> TensorPolicy:
    """``policy`` as a function of the carried entries: on tensors for an
    :class:`~sde_torchrl.modules.sde_actor.SDEActor` over one
    :class:`~sde_torchrl.modules.actors.LatentMLPActor`, squashed or not, and for SAC's
    tanh-squashed Gaussian over :class:`~sde_torchrl.modules.sac_actor.GaussianHeads` (the
    numbers their ``forward`` writes), else the policy called on a tensordict of them."""
    actor = _latent_actor(policy)
    if actor is not None:
        return _sde_policy(policy, actor)
    return _tanh_normal_policy(policy) if _is_tanh_normal_heads(policy) else _tensordict_policy(policy)


def deterministic_policy(policy: object) -> TensorPolicy:
    """``policy``'s deterministic action as a function of the carried entries (under
    ``ExplorationType.DETERMINISTIC``): the mean ``loc`` of an unsquashed
    :class:`~sde_torchrl.modules.sde_actor.SDEActor` over one
    :class:`~sde_torchrl.modules.actors.LatentMLPActor`, else the policy's on a tensordict."""
    actor = _latent_actor(policy)
    if actor is None or policy.squash:
        return _tensordict_policy(policy)
    return lambda carried: {policy.action_key: actor.loc_and_features(carried[actor.in_keys[0]])[0]}


def _latent_actor(policy: object) -> LatentMLPActor | None:
    """The actor of an SDE policy over one :class:`LatentMLPActor`, alone or alone in a
    ``TensorDictSequential`` (what the tensor path computes itself), else ``None``."""
    if not isinstance(policy, SDEActor) or len(policy.actor_modules) != 1:
        return None
    (actor,), sde = policy.actor_modules, policy.sde
    if type(actor) is TensorDictSequential and len(actor.module) == 1:
        (actor,) = actor.module
    fits = isinstance(actor, LatentMLPActor) and list(actor.out_keys) == [sde.loc_key, sde.feature_key]
    return actor if fits else None


def _tensordict_policy(policy: object) -> TensorPolicy:
    def call(carried: dict[NestedKey, torch.Tensor]) -> dict[NestedKey, torch.Tensor]:
        return dict(policy(TensorDict(carried, batch_size=next(iter(carried.values())).shape[:1])).items())

    return call


def _sde_policy(policy: SDEActor, actor: LatentMLPActor) -> TensorPolicy:
    """The policy's exploring step on tensors: the action and its log-density
    (:func:`~sde_torchrl.modules.distribution.sde_sample_and_log_prob`) or, squashed, also the
    pre-squash sample (:func:`~sde_torchrl.modules.distribution.tanh_sde_sample_and_log_prob`)."""
    sde = policy.sde
    keys = sde.dist_keys
    in_key, noise_key, gaussian_key = actor.in_keys[0], keys["noise"], keys.get("gaussian_noise")
    loc_key, feature_key, sigma_key, scale_key = sde.loc_key, sde.feature_key, sde.sigma_key, sde.gaussian_scale_key
    action_key, log_prob_key, sample_key = policy.action_key, policy.log_prob_key, policy.sample_key
    low_high = policy.bounds
    mid_half: dict[tuple[torch.dtype, torch.device], tuple[torch.Tensor, torch.Tensor]] = {}

    def act(carried: dict[NestedKey, torch.Tensor]) -> dict[NestedKey, torch.Tensor]:
        loc, features = actor.loc_and_features(carried[in_key])
        sigma, scale = sde.batch_params(loc)
        out = {loc_key: loc, feature_key: features, sigma_key: sigma}
        gaussian = None
        if scale is not None:
            out[scale_key], gaussian = scale, carried[gaussian_key]
        if low_high is None:
            action, log_prob = sde_sample_and_log_prob(loc, sigma, features, carried[noise_key], scale, gaussian)
        else:
            like = (loc.dtype, loc.device)
            if like not in mid_half:  # the bounds in the policy's dtype, as its distribution casts them
                mid_half[like] = tanh_bounds(*(bound.to(loc.device) for bound in low_high), loc.dtype)
            out[sample_key], action, log_prob = tanh_sde_sample_and_log_prob(
                loc, sigma, features, carried[noise_key], mid_half[like], scale, gaussian)
        out[action_key], out[log_prob_key] = action, log_prob
        return out

    return act


def _is_tanh_normal_heads(policy: object) -> bool:
    """Whether ``policy`` is SAC's Gaussian as :func:`~sde_torchrl.modules.sac_actor.make_sac_networks`
    builds it: ``GaussianHeads`` writing the ``TanhNormal``'s ``loc`` and ``scale``, sampled
    once per step from torch's global generator."""
    if type(policy) is not ProbabilisticActor or len(policy.module) != 2:
        return False
    heads, sampler = policy.module
    return (type(heads) is TensorDictModule and isinstance(heads.module, GaussianHeads)
            and sampler.distribution_class is TanhNormal and tuple(sampler.dist_keys) == ("loc", "scale")
            and list(sampler.in_keys) == list(heads.out_keys) and len(sampler.dist_sample_keys) == 1
            and sampler.return_log_prob and sampler.num_samples is None and not getattr(sampler, "safe", False)
            and getattr(sampler, "_generator", None) is None and getattr(sampler, "_generator_key", None) is None)


def _tanh_normal_policy(policy: ProbabilisticActor) -> TensorPolicy:
    """SAC's Gaussian step on tensors: the heads' ``loc`` and ``scale``, then one reparameterised
    draw of the ``TanhNormal`` scored with it (TorchRL's ``sample_and_log_prob``), as the actor's
    ``forward`` calls them."""
    heads, sampler = policy.module
    in_key, (loc_key, scale_key) = heads.in_keys[0], heads.out_keys
    action_key, log_prob_key, bounds = sampler.dist_sample_keys[0], sampler.log_prob_key, sampler.distribution_kwargs

    def act(carried: dict[NestedKey, torch.Tensor]) -> dict[NestedKey, torch.Tensor]:
        loc, scale = heads.module(carried[in_key])
        dist = TanhNormal(loc=loc, scale=scale, **bounds)
        action, log_prob = sample_and_log_prob(dist, torch.Size(), reparameterize=dist.has_rsample)
        return {loc_key: loc, scale_key: scale, action_key: action, log_prob_key: log_prob}

    return act


def fused_rollout(
    env: FusedEnv, act: TensorPolicy, carried: TensorDictBase, steps: int, keep: Sequence[NestedKey] | None
) -> tuple[TensorDict, TensorDict]:
    """``steps`` steps of every env from ``carried``, resetting the done envs alone.

    Args:
        env: the env's parts (:func:`fused_env`).
        act: the policy on tensors (:func:`tensor_policy`).
        carried: where the rollout starts (a reset's or the last step's output, the policy's
            entries of that step included).
        steps: steps per env.
        keep: the keys to keep of each step (``None``: all).

    Returns:
        ``(rollout [n_envs, steps], carried)``: what ``steps`` calls of
        ``env.step_and_maybe_reset(policy(td))`` give, stacked, and the state after them.
    """
    batch = carried.batch_size
    state: dict[NestedKey, torch.Tensor] = dict(carried.items())
    primer, normalizer = env.primer, env.normalizer
    noise_keys = tuple(key for key in _noise_keys(primer) if key in state)
    wanted = None if keep is None else set(keep)
    columns: dict[NestedKey, list[torch.Tensor]] = {}

    def record(key: NestedKey, value: torch.Tensor) -> None:
        if wanted is None or key in wanted:
            columns.setdefault(key, []).append(value)

    for _ in range(steps):
        state.update(act(state))
        for key, value in state.items():
            record(key, value)
        obs, reward, terminated, truncated = (torch.as_tensor(a) for a in env.base.step_arrays(
            state["action"].detach().cpu().numpy()))
        done = terminated | truncated
        after: dict[NestedKey, torch.Tensor] = {"observation": obs, "reward": reward, "done": done,
                                                "terminated": terminated, "truncated": truncated}
        if env.episode_key is not None:
            after[env.episode_key] = state[env.episode_key] + reward
        if normalizer is not None:
            after["observation"], after["reward"] = normalizer.observe(obs, reward, done)
        if noise_keys:
            held = tuple(state.get(key) for key in _noise_keys(primer))
            drawn = primer.step_noise(*held, done)
            after.update((key, value) for key, value in zip(_noise_keys(primer), drawn or held, strict=True)
                         if key in noise_keys)
        for key, value in after.items():
            record(("next", key), value)
        del after["reward"]
        state.update(after)
        if bool(done.any()):
            _reset_done(env, state, done.reshape(batch), noise_keys)
    rollout = TensorDict({key: torch.stack(values, dim=1) for key, values in columns.items()},
                         batch_size=(*batch, steps))
    carried = TensorDict(state, batch_size=batch)
    if noise_keys:
        primer.hold(carried)  # what the reference path's primer keeps for its next reset
    return rollout, carried


def fused_episodes(env: FusedEnv, act: TensorPolicy, steps: int) -> TensorDict:
    """One episode per env from a full reset, each env stepped to its episode's end and no
    further, for at most ``steps`` steps; the rollout ends with the longest episode.

    What ``env.rollout(steps, policy, break_when_any_done=False, break_when_all_done=True)``
    gives under deterministic exploration, for the keys an evaluation reads: ``("next",
    "reward")`` and ``("next", "done")``, ``[n_envs, T]`` (an env's rows after its episode's end
    hold reward 0 and ``done``). The normaliser, if any, must be frozen (raw rewards, no updates).

    Args:
        env: the env's parts (:func:`fused_env`).
        act: the deterministic policy on tensors (:func:`deterministic_policy`).
        steps: the longest episode allowed.
    """
    n = env.base.batch_size[0]
    obs = torch.as_tensor(env.base.reset_arrays())
    state: dict[NestedKey, torch.Tensor] = {"observation": obs}
    if env.primer is not None:  # the primer's defaults (no draws when deterministic), for a policy that reads them
        defaults = env.primer.primers.zero()
        state.update((defaults if defaults.batch_size else defaults.expand(n)).items())
    if env.normalizer is not None:
        state["observation"] = env.normalizer.normalize(obs)
    ended = torch.zeros(n, 1, dtype=torch.bool)
    rewards, dones = [], []
    for _ in range(steps):
        action = act(state)["action"]
        active = (~ended).flatten().nonzero().flatten().tolist()
        obs, reward, terminated, truncated = (torch.as_tensor(a) for a in env.base.step_arrays(
            action.detach().cpu().numpy(), active))
        if env.normalizer is not None:
            obs, reward = env.normalizer.observe(obs, reward, terminated | truncated)
        ended = ended | terminated | truncated
        state["observation"] = obs
        rewards.append(reward)
        dones.append(ended)
        if bool(ended.all()):
            break
    return TensorDict({("next", "reward"): torch.stack(rewards, 1), ("next", "done"): torch.stack(dones, 1)},
                      batch_size=(n, len(rewards)))


def _reset_done(env: FusedEnv, state: dict[NestedKey, torch.Tensor], reset: torch.Tensor,
                noise_keys: tuple[NestedKey, ...]) -> None:
    """Resets the envs where ``reset``, in ``state``: what TorchRL's ``maybe_reset`` writes."""
    if not bool(reset.all()):  # a partial reset zeroes there what it does not write (the policy's entries)
        written = {"observation", *FLAGS, env.episode_key, *noise_keys}
        for key, value in state.items():
            if key not in written:
                state[key] = value.masked_fill(expand_as_right(reset, value), 0)
    obs = torch.as_tensor(env.base.reset_arrays(reset.tolist()))
    if env.normalizer is not None:
        obs = env.normalizer.normalize(obs)
    state["observation"] = torch.where(expand_as_right(reset, obs), obs, state["observation"])
    for flag in FLAGS:
        state[flag] = state[flag] & ~expand_as_right(reset, state[flag])
    if env.episode_key is not None:
        total = state[env.episode_key]
        state[env.episode_key] = torch.where(expand_as_right(~reset, total), total, 0.0)
    if not noise_keys:
        return
    primer = env.primer
    noise, gaussian, age = (state.get(key) for key in _noise_keys(primer))
    fresh = primer.reset_noise(reset, noise, gaussian, age, None if age is None else (noise, age))
    state.update((key, value) for key, value in zip(_noise_keys(primer), fresh, strict=True) if key in noise_keys)


def _noise_keys(primer: SDENoisePrimer | None) -> tuple[NestedKey, ...]:
    """The primer's keys in the order its methods take them: ``ξ``, ``ε``, the count."""
    return () if primer is None else (primer.noise_key, primer.gaussian_noise_key, primer.age_key)


def _flatten(transform: object) -> list:
    return [t for inner in transform for t in _flatten(inner)] if isinstance(transform, Compose) else [transform]


__all__ = ["FusedEnv", "deterministic_policy", "fused_env", "fused_episodes", "fused_rollout", "tensor_policy"]
