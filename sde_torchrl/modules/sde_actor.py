"""The SDE policy: :class:`SDEActor`, a ``ProbabilisticActor`` over the SDE distribution.

One form serves the episodic estimators (REINFORCE, GPOMDP, ENAC) and TorchRL's losses (PPO,
A2C, SAC): ``SDEActor(TensorDictSequential(actor, sde))`` with ``sde`` an
:class:`~sde_torchrl.modules.sde.SDEParams`, built by :func:`make_sde_actor`. The actor writes
the controller's mean, ``SDEParams`` writes ``σ̂`` beside it, the env's
:class:`~sde_torchrl.modules.noise.SDENoisePrimer` carries the noise ``ξ``, and the actor samples
:class:`~sde_torchrl.modules.distribution.SDENormal` (or the squashed
:class:`~sde_torchrl.modules.distribution.TanhSDENormal`) from those entries. TorchRL's losses
call its ``get_dist`` on stored data; the episodic estimators score the pre-squash sample it
stores (the tanh Jacobian does not depend on the parameters, so its score is exact).
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import InteractionType, TensorDictModuleBase, TensorDictSequential
from tensordict.utils import NestedKey
from torchrl.data import Bounded, Composite, TensorSpec
from torchrl.modules import ProbabilisticActor

from sde_torchrl.modules.distribution import SDENormal, TanhSDENormal, sde_sample_and_log_prob
from sde_torchrl.modules.noise import ADD_PRIMER, deterministic_exploration
from sde_torchrl.modules.sde import SDEParams


class SDEActor(ProbabilisticActor):
    """The SDE policy as a ``ProbabilisticActor`` that also keeps the pre-squash sample.

    Samples the distribution built from ``actor`` and ``sde``'s entries with the carried noise:
    ``u = loc + (σ̂ ⊙ ξ) x [+ σ_gauss ε]`` (eqs. 17-19, 22), the action ``a = u`` or, squashed,
    ``a = mid + half · tanh(u)``. Writes the action, its log-probability under the distribution
    (``dist.log_prob(a)``, what PPO's ratio compares) and, when squashed, ``u`` under
    ``sample_key``: what the episodic estimators score. Unsquashed, a step computes the two without
    building the distribution (:func:`~sde_torchrl.modules.distribution.sde_sample_and_log_prob`,
    the same numbers). Under deterministic exploration the action is the distribution's
    ``deterministic_sample`` and ``u = loc``. ``get_dist`` and
    everything else TorchRL's losses use are ``ProbabilisticActor``'s; the likelihood (eq. 20)
    does not depend on ``ξ``, so a loss that only scores stored actions (PPO, A2C) may leave the
    noise out of its minibatches, while sampling (this forward, SAC's ``rsample``) needs it.

    Raises:
        KeyError: sampling with no noise in the input (the env has no noise primer).

    Args:
        module: ``TensorDictSequential(actor, sde)``, the actor writing ``sde.loc_key``.
        sde: the :class:`~sde_torchrl.modules.sde.SDEParams` module inside ``module``.
        squash: squash into ``[low, high]`` (:class:`~sde_torchrl.modules.distribution.TanhSDENormal`).
        low: lower bounds for ``squash``.
        high: upper bounds for ``squash``.
        action_key: where the action is written.
        sample_key: where the pre-squash sample is written (``squash`` only; unsquashed, it is
            the action).
        log_prob_key: where the log-probability is written.

    Examples:
        >>> from tensordict import TensorDict
        >>> from sde_torchrl import LinearActor
        >>> sde = SDEParams(action_dim=2, feature_dim=3)
        >>> policy = SDEActor(TensorDictSequential(LinearActor(3, 2), sde), sde, squash=True, low=-1.0, high=1.0)
        >>> td = policy(TensorDict({"observation": torch.randn(5, 3), "sde_noise": torch.randn(5, 2, 3)}, [5]))
        >>> bool((td["action"] == torch.tanh(td["action_sample"])).all()), td["action_log_prob"].shape
        (True, torch.Size([5]))
    """

    def __init__(
        self,
        module: TensorDictSequential,
        sde: SDEParams,
        *,
        squash: bool = False,
        low: torch.Tensor | float | None = None,
        high: torch.Tensor | float | None = None,
        action_key: NestedKey = "action",
        sample_key: NestedKey = "action_sample",
        log_prob_key: NestedKey = "action_log_prob",
    ) -> None:
        kwargs = {"low": torch.as_tensor(low), "high": torch.as_tensor(high)} if squash else {}
        super().__init__(
            module, in_keys=sde.dist_keys, out_keys=[action_key],
            distribution_class=TanhSDENormal if squash else SDENormal, distribution_kwargs=kwargs,
            return_log_prob=True, log_prob_key=log_prob_key, default_interaction_type=InteractionType.RANDOM,
        )
        self.squash, self.action_key = squash, action_key
        self.sample_key = sample_key if squash else action_key
        if squash:
            self.out_keys = [*self.out_keys, sample_key]

    @property
    def bounds(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """``(low, high)`` of the squash, ``None`` unsquashed."""
        kwargs = self.module[-1].distribution_kwargs
        return (kwargs["low"], kwargs["high"]) if self.squash else None

    @property
    def log_prob_key(self) -> NestedKey:
        """Where the log-probability of the action is written."""
        return self.module[-1].log_prob_key

    @property
    def sde(self) -> SDEParams:
        """The :class:`~sde_torchrl.modules.sde.SDEParams` module (the last of ``module``)."""
        return self.module[0].module[-1]

    @property
    def actor_modules(self) -> tuple[TensorDictModuleBase, ...]:
        """The modules before ``SDEParams``, in order: they write the controller's mean."""
        return tuple(self.module[0].module[:-1])

    @property
    def actor(self) -> TensorDictSequential:
        """The modules before ``SDEParams`` (:attr:`actor_modules`) chained."""
        return TensorDictSequential(*self.actor_modules)

    def forward(self, tensordict: TensorDictBase, tensordict_out: TensorDictBase | None = None,
                **kwargs) -> TensorDictBase:
        tensordict = self.get_dist_params(tensordict, **kwargs)
        out = tensordict if tensordict_out is None else tensordict_out
        if not self.squash and not deterministic_exploration():  # what a collection step writes, and no more
            params = {name: tensordict.get(key, None) for name, key in self.sde.dist_keys.items()}
            if all(value is not None for value in params.values()):
                action, log_prob = sde_sample_and_log_prob(**params)
                out.set(self.action_key, action)
                out.set(self.log_prob_key, log_prob)
                return out
        dist = self.build_dist_from_params(tensordict)
        if deterministic_exploration():
            sample, action = dist.loc, dist.deterministic_sample
        elif dist.noise is None:  # sampling needs the carried ξ; a loss's get_dist does not
            raise KeyError(f"SDE noise {self.sde.noise_key!r} missing from the input: {ADD_PRIMER}")
        else:
            sample = SDENormal.rsample(dist)
            action = dist.squash(sample) if self.squash else sample
        out.set(self.action_key, action)
        out.set(self.log_prob_key, dist.log_prob(action))
        if self.squash:
            out.set(self.sample_key, sample)
        return out


def action_bounds(spec: TensorSpec, action_key: NestedKey = "action") -> tuple[torch.Tensor, torch.Tensor]:
    """``(low, high)`` of a ``Bounded`` action spec (an env's ``action_spec`` or ``full_action_spec``).

    Args:
        spec: the action spec, or a ``Composite`` holding it under ``action_key``.
        action_key: key of the action in a ``Composite``.

    Returns:
        The lower and upper bounds.

    Raises:
        ValueError: if the action spec has no finite bounds.

    Examples:
        >>> from torchrl.envs import GymEnv
        >>> action_bounds(GymEnv("Pendulum-v1").action_spec)
        (tensor([-2.]), tensor([2.]))
    """
    if isinstance(spec, Composite):
        spec = spec[action_key]
    if not isinstance(spec, Bounded):
        raise ValueError(
            f"action spec {type(spec).__name__} has no bounds: a squashed SDE actor needs a Bounded "
            "action spec, or low= and high="
        )
    return spec.space.low.clone(), spec.space.high.clone()


def make_sde_actor(
    actor: TensorDictModuleBase,
    sde: SDEParams,
    *,
    squash: bool = False,
    action_spec: TensorSpec | None = None,
    low: torch.Tensor | float | None = None,
    high: torch.Tensor | float | None = None,
    action_key: NestedKey = "action",
    sample_key: NestedKey = "action_sample",
) -> SDEActor:
    """The SDE policy, for the episodic estimators and for TorchRL's losses and collectors alike.

    Builds ``SDEActor(TensorDictSequential(actor, sde), sde, ...)``: a ``ProbabilisticActor``
    over :class:`~sde_torchrl.modules.distribution.SDENormal` (``TanhSDENormal`` with
    ``squash``), acting randomly unless TorchRL's exploration type says otherwise. With
    ``squash`` the bounds come from ``low``/``high`` or from ``action_spec``. The env needs the
    noise primer, ``sde.make_tensordict_primer()``.

    Args:
        actor: writes the controller's mean under ``sde.loc_key``.
        sde: the :class:`~sde_torchrl.modules.sde.SDEParams` module.
        squash: squash into the action bounds (:class:`~sde_torchrl.modules.distribution.TanhSDENormal`).
        action_spec: the env's action spec: checked against ``sde.action_dim``, and the bounds
            when ``squash`` is set and ``low``/``high`` are not given.
        low: lower bounds for ``squash``.
        high: upper bounds for ``squash``.
        action_key: where the action is written.
        sample_key: where the pre-squash sample is written (``squash`` only).

    Returns:
        The :class:`SDEActor`; its log-prob key is ``action_log_prob``.

    Raises:
        ValueError: if the actor does not write ``sde.loc_key``, if the action spec's size differs
            from ``sde.action_dim``, or if ``squash`` has no bounds to use.

    Examples:
        >>> from tensordict.nn import TensorDictModule
        >>> from torch import nn
        >>> from torchrl.envs import GymEnv, TransformedEnv
        >>> env = GymEnv("Pendulum-v1")
        >>> sde = SDEParams(action_dim=1, feature_dim=3)
        >>> env = TransformedEnv(env, sde.make_tensordict_primer())
        >>> actor = TensorDictModule(nn.Linear(3, 1), in_keys=["observation"], out_keys=["loc"])
        >>> policy = make_sde_actor(actor, sde, squash=True, action_spec=env.action_spec)
        >>> td = env.rollout(5, policy)
        >>> bool((td["action"].abs() <= 2).all()), td["action_log_prob"].shape
        (True, torch.Size([5]))
    """
    out_keys = list(getattr(actor, "out_keys", []))
    if sde.loc_key not in out_keys:
        raise ValueError(
            f"the actor writes {out_keys} but SDEParams reads the mean from {sde.loc_key!r}: build the actor "
            f"with out_keys=[{sde.loc_key!r}], or SDEParams(loc_key={out_keys[0] if out_keys else '...'!r})"
        )
    if action_spec is not None:
        spec = action_spec[action_key] if isinstance(action_spec, Composite) else action_spec
        if spec.shape[-1:] != (sde.action_dim,):
            raise ValueError(
                f"the env's action spec has shape {tuple(spec.shape)}, SDEParams action_dim={sde.action_dim}"
            )
    if squash and (low is None or high is None):
        if action_spec is None:
            raise ValueError("squash=True needs low= and high=, or the env's action_spec=")
        spec_low, spec_high = action_bounds(action_spec, action_key)
        low, high = (spec_low if low is None else low), (spec_high if high is None else high)
    return SDEActor(TensorDictSequential(actor, sde), sde, squash=squash, low=low, high=high,
                    action_key=action_key, sample_key=sample_key)


__all__ = ["SDEActor", "action_bounds", "make_sde_actor"]
