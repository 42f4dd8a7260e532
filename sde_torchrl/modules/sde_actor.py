"""An SDE policy that TorchRL's losses accept: a parameter module, its noise schedule and the actor.

TorchRL's PPO, A2C and SAC losses take a probabilistic module (``ProbabilisticActor``) and call
its ``get_dist`` on stored data. The SDE policy is built from three pieces:

* :class:`SDEParams`, a deterministic module that writes ``σ̂ = expln(p)`` (eq. 23, optionally
  with eq. 22's Gaussian scale) beside the controller's ``loc``; it draws nothing, so re-running
  it on stored data (what the losses do) changes nothing;
* :class:`SDENoisePrimer`, the env transform from :meth:`SDEParams.make_tensordict_primer` that
  keeps the noise ``ξ`` in the tensordict: a fresh draw at every full or partial reset, then held
  for the episode (SDE), redrawn every step (REX) or every ``n`` steps;
* :class:`~sde_torchrl.modules.distribution.SDENormal` (or :class:`~sde_torchrl.modules.distribution.TanhSDENormal`),
  built by ``ProbabilisticActor`` from those entries; :func:`make_sde_actor` wires the three.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import InteractionType, TensorDictModuleBase, TensorDictSequential
from tensordict.utils import NestedKey, expand_as_right
from torchrl.data import Bounded, Composite, TensorSpec, Unbounded
from torchrl.envs import TensorDictPrimer
from torchrl.envs.transforms.utils import _get_reset
from torchrl.modules import ProbabilisticActor

from sde_torchrl.modules.distribution import SDENormal, TanhSDENormal
from sde_torchrl.modules.exploration import SCHEDULES, SDESigma, deterministic_exploration
from sde_torchrl.utils.checks import one_of, positive_int
from sde_torchrl.utils.rng import RunStreams, draw_normal
from sde_torchrl.utils.shapes import align

_ADD_PRIMER = (
    "append sde.make_tensordict_primer() to the env (TransformedEnv(env, sde.make_tensordict_primer())), "
    "or pass auto_register_policy_transforms=True to torchrl's Collector"
)


class SDENoisePrimer(TensorDictPrimer):
    """Env transform carrying the SDE noise ``ξ`` (``[A, S]`` per env) and its schedule.

    At every full or partial reset the reset envs get a fresh standard-normal ``ξ`` (and
    ``sde_age = 0``); after each step ``ξ`` is held (``"episode"``: the paper's SDE), redrawn
    (``"step"``: REX, paper section 4.1) or redrawn once ``n`` steps have used it (``"every_n"``,
    gSDE's sampling frequency). Being a ``TensorDictPrimer``, TorchRL's ``Collector`` recognises
    it and does not add it twice.

    Args:
        action_dim: ``A``.
        feature_dim: ``S``.
        schedule: ``"episode"``, ``"step"`` or ``"every_n"``.
        every_n: redraw period for ``"every_n"``.
        noise_key: the tensordict key of ``ξ``.
        age_key: steps the current ``ξ`` has been used (``"every_n"`` only).
        dtype: dtype of ``ξ`` (the policy's).
        streams: per-run streams over the env's leading batch dimension, or ``None`` for torch's
            global generator.

    Examples:
        >>> from torchrl.envs import GymEnv, TransformedEnv
        >>> env = TransformedEnv(GymEnv("Pendulum-v1"), SDENoisePrimer(1, 3, schedule="step"))
        >>> env.reset()["sde_noise"].shape
        torch.Size([1, 3])
    """

    def __init__(
        self,
        action_dim: int,
        feature_dim: int,
        *,
        schedule: str = "episode",
        every_n: int | None = None,
        noise_key: NestedKey = "sde_noise",
        age_key: NestedKey = "sde_age",
        dtype: torch.dtype = torch.float32,
        streams: RunStreams | None = None,
    ) -> None:
        one_of("schedule", schedule, SCHEDULES)
        specs = {noise_key: Unbounded(shape=(positive_int("action_dim", action_dim),
                                              positive_int("feature_dim", feature_dim)), dtype=dtype)}
        if schedule == "every_n":
            positive_int("every_n", every_n)
            specs[age_key] = Unbounded(shape=(1,), dtype=torch.int64)
        super().__init__(Composite(specs), default_value=0, expand_specs=True)
        self.schedule, self.every_n, self.streams = schedule, every_n, streams
        self.noise_key, self.age_key, self.noise_dtype = noise_key, age_key, dtype

    def _fresh(self, like: torch.Tensor) -> torch.Tensor:
        return draw_normal(like.shape, self.streams).to(dtype=self.noise_dtype, device=like.device)

    def _reset_func(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        tensordict_reset = super()._reset_func(tensordict, tensordict_reset)
        noise = tensordict_reset.get(self.noise_key, None)
        if noise is not None:  # absent when no env is reset
            reset = _get_reset(self.reset_key, tensordict)
            fresh = self._fresh(noise)
            tensordict_reset.set(self.noise_key, torch.where(expand_as_right(reset, fresh), fresh, noise))
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict = super()._step(tensordict, next_tensordict)  # carries ξ (and the age) over
        if self.schedule == "episode":
            return next_tensordict
        noise = next_tensordict.get(self.noise_key)
        fresh = self._fresh(noise)
        if self.schedule == "step":
            next_tensordict.set(self.noise_key, fresh)
            return next_tensordict
        age = next_tensordict.get(self.age_key) + 1
        redraw = age >= self.every_n
        next_tensordict.set(self.age_key, torch.where(redraw, 0, age))
        next_tensordict.set(self.noise_key, torch.where(redraw.unsqueeze(-1), fresh, noise))
        return next_tensordict


class SDEParams(SDESigma):
    """Writes the parameters of :class:`~sde_torchrl.modules.distribution.SDENormal` next to the actor's ``loc``.

    Reads ``loc`` (the controller's mean, eq. 17), the exploration features ``x`` and checks the
    carried noise ``ξ``; writes ``σ̂ = expln(p)`` (eqs. 23, 24) expanded to the batch
    (``sde_sigma_hat``, ``[*, A, S]``) and, with eq. (22)'s Gaussian part, its per-action scale
    ``σ_gauss = expln(q)`` (``sde_gaussian_scale``). It draws nothing: the noise is drawn by the
    env transform from :meth:`make_tensordict_primer`, so a loss that re-runs the policy on
    stored data rebuilds exactly the distribution the action was drawn from. The parameters
    (``sigma_param``, ``gaussian_param``), sharing modes, run stacking and the per-step
    likelihood (:meth:`~sde_torchrl.modules.exploration.SDESigma.log_prob`, the number
    :class:`~sde_torchrl.modules.distribution.SDENormal` gives) are
    :class:`~sde_torchrl.modules.exploration.SDESigma`'s, shared with
    :class:`~sde_torchrl.modules.exploration.StateDependentExplorer`.

    Args:
        action_dim: ``A``.
        feature_dim: ``S``.
        schedule: noise schedule of the primer: ``"episode"`` (SDE), ``"step"`` (REX) or
            ``"every_n"``.
        every_n: redraw period for ``"every_n"``.
        sharing: one ``σ̂`` per matrix element (``"element"``), per action (``"action"``) or one
            (``"single"``) (paper section 2.3, footnote 1).
        init_param: initial ``p``; the paper starts at -2 (``σ̂ ≈ 0.135``).
        gaussian_init_param: initial ``q`` of eq. (22)'s i.i.d. Gaussian part, ``None`` for none.
        learn_sigma: ``p`` (and ``q``) as parameters, or as fixed buffers.
        runs: independent runs stacked along a leading dimension, or ``None``.
        loc_key: where the actor writes its mean.
        feature_key: the features ``x`` that ``Θ̂`` sees (the observation by default; a latent
            layer for gSDE-style features).
        noise_key: the carried ``ξ``.
        sigma_key: where ``σ̂`` is written.
        gaussian_scale_key: where ``σ_gauss`` is written (eq. 22 only).
        age_key: the primer's step counter (``"every_n"`` only).

    Attributes:
        streams: per-run :class:`~sde_torchrl.utils.rng.RunStreams` for the primer's draws when runs
            are stacked (the env's leading batch dimension); set it before
            :meth:`make_tensordict_primer`. ``None``: torch's global generator.

    Examples:
        >>> from tensordict import TensorDict
        >>> sde = SDEParams(action_dim=2, feature_dim=3)
        >>> td = TensorDict({"loc": torch.zeros(5, 2), "observation": torch.randn(5, 3),
        ...                  "sde_noise": torch.randn(5, 2, 3)}, [5])
        >>> sde(td)["sde_sigma_hat"].shape
        torch.Size([5, 2, 3])
        >>> sorted(sde.dist_keys)
        ['features', 'loc', 'noise', 'sigma_hat']
    """

    def __init__(
        self,
        action_dim: int,
        feature_dim: int,
        *,
        schedule: str = "episode",
        every_n: int | None = None,
        sharing: str = "element",
        init_param: float = -2.0,
        gaussian_init_param: float | None = None,
        learn_sigma: bool = True,
        runs: int | None = None,
        loc_key: NestedKey = "loc",
        feature_key: NestedKey = "observation",
        noise_key: NestedKey = "sde_noise",
        sigma_key: NestedKey = "sde_sigma_hat",
        gaussian_scale_key: NestedKey = "sde_gaussian_scale",
        age_key: NestedKey = "sde_age",
    ) -> None:
        super().__init__(
            action_dim, feature_dim, schedule=schedule, every_n=every_n, sharing=sharing, init_param=init_param,
            gaussian_init_param=gaussian_init_param, learn_sigma=learn_sigma, runs=runs, loc_key=loc_key,
            feature_key=feature_key,
        )
        self.noise_key = noise_key
        self.sigma_key, self.gaussian_scale_key, self.age_key = sigma_key, gaussian_scale_key, age_key
        self.in_keys = [loc_key, feature_key, noise_key]
        self.out_keys = [sigma_key] + ([gaussian_scale_key] if self.has_gaussian else [])

    @property
    def dist_keys(self) -> dict[str, NestedKey]:
        """``in_keys`` for ``ProbabilisticActor``: distribution argument -> tensordict key."""
        keys = {"loc": self.loc_key, "sigma_hat": self.sigma_key, "features": self.feature_key,
                "noise": self.noise_key}
        if self.has_gaussian:
            keys["gaussian_scale"] = self.gaussian_scale_key
        return keys

    def make_tensordict_primer(self) -> SDENoisePrimer:
        """The env transform that draws ``ξ`` at (partial) resets and redraws it on schedule.

        TorchRL's ``Collector(..., auto_register_policy_transforms=True)`` finds and appends it.
        """
        return SDENoisePrimer(
            self.action_dim, self.feature_dim, schedule=self.schedule, every_n=self.every_n,
            noise_key=self.noise_key, age_key=self.age_key, dtype=self.sigma_param.dtype,
            streams=self.streams,
        )

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        loc = self._get(tensordict, self.loc_key, "the actor must write its mean there "
                        f"(out_keys=[{self.loc_key!r}]), or pass loc_key= to SDEParams")
        features = self._get(tensordict, self.feature_key, "pass feature_key= to SDEParams")
        self._check_shapes(loc, features)
        if self.noise_key not in tensordict.keys(True) and not deterministic_exploration():
            raise KeyError(f"SDE noise {self.noise_key!r} missing from the input: {_ADD_PRIMER}")
        batch, batch_dims = loc.shape[:-1], loc.dim() - 1
        sigma = align(self.sde_sigma, self.run_dims, batch_dims).to(loc.dtype)
        tensordict.set(self.sigma_key, sigma.expand(*batch, self.action_dim, self.feature_dim))
        if self.has_gaussian:
            scale = self.gaussian_scale(batch_dims).to(loc.dtype)
            tensordict.set(self.gaussian_scale_key, scale.expand(*batch, self.action_dim))
        return tensordict

    @staticmethod
    def _get(tensordict: TensorDictBase, key: NestedKey, fix: str) -> torch.Tensor:
        value = tensordict.get(key, None)
        if value is None:
            present = sorted(str(k) for k in tensordict.keys(True, True))
            raise KeyError(f"SDEParams reads {key!r}, which is missing (present: {present}): {fix}")
        return value


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
) -> ProbabilisticActor:
    """The SDE policy as TorchRL's losses and collectors take it.

    Builds ``ProbabilisticActor(TensorDictSequential(actor, sde), in_keys=sde.dist_keys,
    distribution_class=SDENormal or TanhSDENormal, return_log_prob=True)``, acting randomly
    unless TorchRL's exploration type says otherwise. With ``squash`` the bounds come from
    ``low``/``high`` or from ``action_spec``.

    Args:
        actor: writes the controller's mean under ``sde.loc_key``.
        sde: the :class:`SDEParams` module.
        squash: squash into the action bounds (:class:`~sde_torchrl.modules.distribution.TanhSDENormal`).
        action_spec: the env's action spec: checked against ``sde.action_dim``, and the bounds
            when ``squash`` is set and ``low``/``high`` are not given.
        low: lower bounds for ``squash``.
        high: upper bounds for ``squash``.
        action_key: where the action is written.

    Returns:
        The ``ProbabilisticActor``; its log-prob key is ``action_log_prob``.

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
    kwargs = {}
    if squash:
        if low is None or high is None:
            if action_spec is None:
                raise ValueError("squash=True needs low= and high=, or the env's action_spec=")
            spec_low, spec_high = action_bounds(action_spec, action_key)
            low, high = (spec_low if low is None else low), (spec_high if high is None else high)
        kwargs = {"low": torch.as_tensor(low), "high": torch.as_tensor(high)}
    return ProbabilisticActor(
        TensorDictSequential(actor, sde),
        in_keys=sde.dist_keys,
        out_keys=[action_key],
        distribution_class=TanhSDENormal if squash else SDENormal,
        distribution_kwargs=kwargs,
        return_log_prob=True,
        default_interaction_type=InteractionType.RANDOM,
    )


__all__ = ["SDENoisePrimer", "SDEParams", "action_bounds", "make_sde_actor"]
