"""State-dependent exploration (SDE), paper section 3: its parameters, :class:`SDEParams`.

The policy adds ``ε̂(x; Θ̂) = Θ̂ x`` to the controller's mean (17)-(19), with
``Θ̂_ji = σ̂_ji ξ_ji`` and ``ξ ~ N(0, 1)``. ``σ̂ = expln(p)`` (23) keeps the standard deviations
positive; i.i.d. Gaussian noise with its own ``σ = expln(q)`` can be added on top (22).

SDE is built from three pieces, each with one job: :class:`SDEParams` (here) holds ``p`` (and
``q``) and writes ``σ̂`` beside the controller's mean; the env transform
:class:`~sde_torchrl.modules.noise.SDENoisePrimer` draws ``ξ`` (the only place that does) and
holds it for an episode (SDE), a step (REX), ``n`` steps, or as SB3 counts (over a rollout);
:class:`~sde_torchrl.modules.sde_actor.SDEActor` samples
:class:`~sde_torchrl.modules.distribution.SDENormal` from those entries. The maths lives in
:mod:`sde_torchrl.modules.distribution`.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import nn

from sde_torchrl.modules.distribution import gaussian_log_prob, sde_variance
from sde_torchrl.modules.noise import AGE_KEY, DEFAULT_SCHEDULE, GAUSSIAN_NOISE_KEY, NOISE_KEY, SDENoisePrimer
from sde_torchrl.utils.checks import noise_schedule, one_of, positive_int
from sde_torchrl.utils.options import SHARINGS, SIGMA_TRANSFORMS
from sde_torchrl.utils.rng import RunStreams
from sde_torchrl.utils.shapes import align


def expln(p: torch.Tensor) -> torch.Tensor:
    """``exp(p)`` for ``p <= 0``, ``ln(p + 1) + 1`` otherwise (eq. 23).

    Smooth, positive and only logarithmically growing; its derivative (24) is ``exp(p)`` below
    zero and ``1 / (p + 1)`` above, both 1 at zero. Each branch sees only its own half of the
    real line, so neither can produce a NaN gradient.

    Args:
        p: unconstrained parameter.

    Returns:
        The standard deviation ``expln(p) > 0``.
    """
    return torch.where(p <= 0, torch.exp(p.clamp(max=0)), torch.log1p(p.clamp(min=0)) + 1)


def expln_inverse(sigma: torch.Tensor | float) -> torch.Tensor:
    """Inverse of :func:`expln`: the parameter ``p`` with ``expln(p) = sigma``.

    Args:
        sigma: a positive standard deviation.

    Returns:
        ``log(sigma)`` for ``sigma <= 1``, ``exp(sigma - 1) - 1`` otherwise.

    Raises:
        ValueError: if any ``sigma`` is not strictly positive and finite.
    """
    if not isinstance(sigma, torch.Tensor):
        sigma = torch.tensor(float(sigma))
    if not bool(torch.isfinite(sigma).all()) or bool((sigma <= 0).any()):
        raise ValueError(f"expln_inverse needs finite sigma > 0, got {sigma}")
    return torch.where(sigma <= 1, torch.log(sigma), torch.expm1(sigma.clamp(min=1) - 1))


def sigma_param_shape(sharing: str, action_dim: int, feature_dim: int) -> tuple[int, int]:
    """Shape of ``p`` (``σ̂ = expln(p)``) for a sharing mode (paper section 2.3, footnote 1).

    Args:
        sharing: one ``σ̂`` per matrix element (``"element"``), per action (``"action"``), one
            for all (``"single"``), or one per feature shared over the actions (``"feature"``,
            SB3's ``full_std=False``, whose ``log_std`` is ``[S, 1]``).
        action_dim: ``A``.
        feature_dim: ``S``.

    Returns:
        ``(A, S)``, ``(A, 1)``, ``(1, 1)`` or ``(1, S)``: broadcastable to the ``A × S`` matrix.

    Examples:
        >>> sigma_param_shape("action", 2, 3), sigma_param_shape("feature", 2, 3)
        ((2, 1), (1, 3))
    """
    shapes = {"element": (action_dim, feature_dim), "action": (action_dim, 1), "feature": (1, feature_dim)}
    return shapes.get(sharing, (1, 1))


def sigma_from_param(p: torch.Tensor, transform: str = "expln") -> torch.Tensor:
    """A standard deviation from its unconstrained parameter: ``expln(p)`` (eq. 23) or ``exp(p)``.

    ``exp`` is SB3's ``use_expln=False`` (its default, ``σ = exp(log_std)``); the two agree for
    ``p <= 0`` and differ above, where ``exp`` grows exponentially and ``expln`` logarithmically.

    Args:
        p: the parameter.
        transform: ``"expln"`` or ``"exp"``.

    Returns:
        ``σ > 0``, the shape of ``p``.

    Examples:
        >>> p = torch.tensor([-1.0, 1.0])
        >>> sigma_from_param(p, "expln"), sigma_from_param(p, "exp")
        (tensor([0.3679, 1.6931]), tensor([0.3679, 2.7183]))
    """
    return expln(p) if transform == "expln" else torch.exp(p)


class SDEParams(TensorDictModuleBase):
    """The parameters of state-dependent exploration, written beside the controller's mean.

    Holds ``p`` with ``σ̂ = expln(p)`` (eqs. 23, 24; or ``exp(p)`` with ``sigma_transform="exp"``),
    one per matrix element, per action, per feature or one for all (``sharing``), and, for eq.
    (22)'s i.i.d. Gaussian part, ``q`` with ``σ_gauss = expln(q)`` (the same transform) per action:
    parameters named ``sigma_param`` and ``gaussian_param``
    (buffers if not learned), stacked over ``runs`` along a leading dimension. Given the
    features ``x``, the action is Gaussian around the controller's mean with
    ``σ_j² = Σ_i (x_i σ̂_ji)² [+ σ_gauss_j²]`` (eq. 20): :meth:`scale` and :meth:`log_prob`, what
    the episodic estimators differentiate.

    As a module it reads the controller's mean (``loc_key``), the features (``feature_key``) and
    checks that the noise ``ξ`` is there; it writes ``σ̂`` expanded to the batch (``sigma_key``,
    ``[*, A, S]``) and, with eq. (22)'s part, ``σ_gauss`` (``gaussian_scale_key``): the entries
    :class:`~sde_torchrl.modules.distribution.SDENormal` is built from. It draws nothing: the
    env transform from :meth:`make_tensordict_primer` draws ``ξ`` (and ``ε``), so a loss that
    re-runs the policy on stored data rebuilds exactly the distribution the action came from.

    Args:
        action_dim: ``A``, size of the action.
        feature_dim: ``S``, size of the exploration features ``x``.
        sharing: one ``σ̂`` per matrix element (``"element"``, ``A×S``), per action
            (``"action"``, ``A``), one for all (``"single"``) (paper section 2.3, footnote 1), or
            one per feature shared over the actions (``"feature"``, ``S``: SB3's ``full_std=False``).
        sigma_transform: ``σ̂ = expln(p)`` (``"expln"``, eq. 23, SB3's ``use_expln=True``) or
            ``exp(p)`` (``"exp"``, SB3's default ``use_expln=False``).
        init_param: initial ``p``; the paper starts at -2 (``σ̂ ≈ 0.135``); SB3's ``log_std_init``
            (both transforms give ``exp(p)`` for ``p <= 0``).
        gaussian_init_param: initial ``q`` of eq. (22)'s i.i.d. Gaussian part, ``None`` for none.
        learn_sigma: ``p`` (and ``q``) as learnable parameters, or as fixed buffers.
        runs: independent runs stacked along a leading parameter dimension, or ``None`` for a
            single, unstacked learner.
        schedule: when the primer redraws ``ξ``: ``"episode"`` (SDE), ``"step"`` (REX) or
            ``"every_n"`` steps of an episode, always at a reset; or counted over a rollout
            whatever the episode boundaries, as SB3's ``sde_sample_freq``: ``"every_n_steps"``
            (``sde_sample_freq=n``) or ``"rollout"`` (``sde_sample_freq=-1``). This and the two
            below are the primer's (:class:`~sde_torchrl.modules.noise.SDENoisePrimer`), checked
            here already and handed to it as they are.
        every_n: redraw period for ``"every_n"`` and ``"every_n_steps"``.
        rollout_steps: steps per rollout for ``"every_n_steps"`` and ``"rollout"`` (TorchRL's
            ``Collector``: ``frames_per_batch // num_envs``), or ``None`` (redraw with
            ``primer.resample(tensordict)``).
        loc_key: where the actor writes the controller's mean.
        feature_key: the features ``x`` that ``Θ̂`` sees (the observation by default; a latent
            layer for gSDE-style features).
        noise_key: the carried ``ξ``.
        gaussian_noise_key: the carried ``ε`` of eq. (22) (with ``gaussian_init_param`` only).
        age_key: steps the current ``ξ`` has been used (``"every_n"``) or steps into the rollout
            (``"every_n_steps"``, ``"rollout"``).
        sigma_key: where ``σ̂`` is written.
        gaussian_scale_key: where ``σ_gauss`` is written (eq. 22 only).

    Attributes:
        streams: per-run :class:`~sde_torchrl.utils.rng.RunStreams` for the primer's draws when
            runs are stacked (the env's leading batch dimension); set it before
            :meth:`make_tensordict_primer`. ``None``: torch's global generator.

    Raises:
        ArgumentError: for an option that is not allowed, named.

    Examples:
        >>> from tensordict import TensorDict
        >>> sde = SDEParams(action_dim=2, feature_dim=3, sharing="action", runs=4)
        >>> sde.sigma_param.shape, sde.sde_sigma.shape
        (torch.Size([4, 2, 1]), torch.Size([4, 2, 3]))
        >>> sde.scale(torch.ones(4, 10, 3)).shape  # eq. 20 per run, step and action
        torch.Size([4, 10, 2])
        >>> td = TensorDict({"loc": torch.zeros(4, 5, 2), "observation": torch.randn(4, 5, 3),
        ...                  "sde_noise": torch.randn(4, 5, 2, 3)}, [4, 5])
        >>> sde(td)["sde_sigma_hat"].shape
        torch.Size([4, 5, 2, 3])
        >>> sorted(sde.dist_keys)
        ['features', 'loc', 'noise', 'sigma_hat']
    """

    def __init__(
        self,
        action_dim: int,
        feature_dim: int,
        *,
        sharing: str = "element",
        sigma_transform: str = "expln",
        init_param: float = -2.0,
        gaussian_init_param: float | None = None,
        learn_sigma: bool = True,
        runs: int | None = None,
        schedule: str = DEFAULT_SCHEDULE,
        every_n: int | None = None,
        rollout_steps: int | None = None,
        loc_key: NestedKey = "loc",
        feature_key: NestedKey = "observation",
        noise_key: NestedKey = NOISE_KEY,
        gaussian_noise_key: NestedKey = GAUSSIAN_NOISE_KEY,
        age_key: NestedKey = AGE_KEY,
        sigma_key: NestedKey = "sde_sigma_hat",
        gaussian_scale_key: NestedKey = "sde_gaussian_scale",
    ) -> None:
        super().__init__()
        self.action_dim = positive_int("action_dim", action_dim)
        self.feature_dim = positive_int("feature_dim", feature_dim)
        self.schedule, self.every_n = noise_schedule(schedule, every_n, rollout_steps=rollout_steps)
        self.rollout_steps = rollout_steps
        self.sharing = one_of("sharing", sharing, SHARINGS)
        self.sigma_transform = one_of("sigma_transform", sigma_transform, SIGMA_TRANSFORMS)
        self.runs = None if runs is None else positive_int("runs", runs)
        self.run_dims = 0 if runs is None else 1
        self.streams: RunStreams | None = None
        run_shape = () if runs is None else (runs,)
        self._register("sigma_param", torch.full(
            run_shape + sigma_param_shape(sharing, action_dim, feature_dim), float(init_param)
        ), learn_sigma)
        self.has_gaussian = gaussian_init_param is not None
        if self.has_gaussian:
            self._register("gaussian_param", torch.full(run_shape + (action_dim,), float(gaussian_init_param)),
                           learn_sigma)
        self.loc_key, self.feature_key, self.noise_key = loc_key, feature_key, noise_key
        self.gaussian_noise_key, self.age_key = gaussian_noise_key, age_key
        self.sigma_key, self.gaussian_scale_key = sigma_key, gaussian_scale_key
        self.in_keys = [loc_key, feature_key, noise_key]
        self.out_keys = [sigma_key] + ([gaussian_scale_key] if self.has_gaussian else [])

    @property
    def dist_keys(self) -> dict[str, NestedKey]:
        """``in_keys`` for ``ProbabilisticActor``: distribution argument → tensordict key."""
        keys = {"loc": self.loc_key, "sigma_hat": self.sigma_key, "features": self.feature_key,
                "noise": self.noise_key}
        if self.has_gaussian:
            keys |= {"gaussian_scale": self.gaussian_scale_key, "gaussian_noise": self.gaussian_noise_key}
        return keys

    def make_tensordict_primer(self) -> SDENoisePrimer:
        """The env transform that draws ``ξ`` (and eq. 22's ``ε``) at (partial) resets and redraws
        it on schedule: the only source of SDE noise.

        TorchRL's ``Collector(..., auto_register_policy_transforms=True)`` finds and appends it.
        """
        return SDENoisePrimer(
            self.action_dim, self.feature_dim, schedule=self.schedule, every_n=self.every_n,
            rollout_steps=self.rollout_steps, gaussian=self.has_gaussian, noise_key=self.noise_key,
            gaussian_noise_key=self.gaussian_noise_key,
            age_key=self.age_key, dtype=self.sigma_param.dtype, streams=self.streams,
        )

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        loc = self._get(tensordict, self.loc_key, "the actor must write its mean there "
                        f"(out_keys=[{self.loc_key!r}]), or pass loc_key= to SDEParams")
        features = self._get(tensordict, self.feature_key, "pass feature_key= to SDEParams")
        self._check_shapes(loc, features)
        sigma, scale = self.batch_params(loc)
        tensordict.set(self.sigma_key, sigma)
        if scale is not None:
            tensordict.set(self.gaussian_scale_key, scale)
        return tensordict

    def batch_params(self, loc: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """``σ̂`` expanded to ``loc``'s batch, ``[*batch, A, S]``, and ``σ_gauss`` to ``[*batch, A]``
        (``None`` for pure SDE), in ``loc``'s dtype: what :meth:`forward` writes."""
        batch, batch_dims = loc.shape[:-1], loc.dim() - 1
        sigma = align(self.sde_sigma, self.run_dims, batch_dims).to(loc.dtype)
        if not self.has_gaussian:
            return sigma.expand(*batch, self.action_dim, self.feature_dim), None
        scale = self.gaussian_scale(batch_dims).to(loc.dtype)
        return sigma.expand(*batch, self.action_dim, self.feature_dim), scale.expand(*batch, self.action_dim)

    @staticmethod
    def _get(tensordict: TensorDictBase, key: NestedKey, fix: str) -> torch.Tensor:
        value = tensordict.get(key, None)
        if value is None:
            present = sorted(str(k) for k in tensordict.keys(True, True))
            raise KeyError(f"SDEParams reads {key!r}, which is missing (present: {present}): {fix}")
        return value

    def _register(self, name: str, value: torch.Tensor, learnable: bool) -> None:
        if learnable:
            self.register_parameter(name, nn.Parameter(value))
        else:
            self.register_buffer(name, value)

    @property
    def sde_sigma(self) -> torch.Tensor:
        """``σ̂ = expln(p)`` (eq. 23; ``exp(p)`` with ``sigma_transform="exp"``) broadcast to the
        full ``[*runs, A, S]`` matrix."""
        sigma = sigma_from_param(self.sigma_param, self.sigma_transform)
        return sigma.expand(*sigma.shape[:-2], self.action_dim, self.feature_dim)

    def exploration_scale(self) -> torch.Tensor:
        """Every ``σ̂`` element per run, ``[*runs, A·S]``: what ``metrics.csv`` reports as
        ``sigma_min`` / ``sigma_max`` (a collapsed exploration shows as ``σ̂ ≈ 0``)."""
        return self.sde_sigma.detach().flatten(-2)

    def gaussian_scale(self, batch_dims: int) -> torch.Tensor | None:
        """``σ_gauss = expln(q)`` (eqs. 22, 23; ``exp(q)`` with ``sigma_transform="exp"``) viewed to
        broadcast against ``[*batch, A]`` data with ``batch_dims`` batch dimensions (runs first), or
        ``None`` for pure SDE."""
        if not self.has_gaussian:
            return None
        return align(sigma_from_param(self.gaussian_param, self.sigma_transform), self.run_dims, batch_dims)

    def scale(self, features: torch.Tensor) -> torch.Tensor:
        """Per-action standard deviation of the action given the features (eqs. 20, 22).

        Args:
            features: ``x`` of shape ``[*batch, S]`` (runs first when stacked).

        Returns:
            ``σ`` of shape ``[*batch, A]`` with ``σ_j² = Σ_i (x_i σ̂_ji)² + σ_gauss_j²``.
        """
        gaussian = self.gaussian_scale(features.dim() - 1)
        return sde_variance(self.sde_sigma, features, gaussian, run_dims=self.run_dims).sqrt()

    def log_prob(self, loc: torch.Tensor, features: torch.Tensor, sample: torch.Tensor) -> torch.Tensor:
        """Per-step log-likelihood ``Σ_j log N(sample_j; loc_j, σ_j²)`` (eqs. 13, 20).

        Autograd of this through ``loc`` and ``σ̂`` gives the paper's scores (14), (16) and (21)
        with the ``expln'`` factor (24). With squashing, scoring the pre-squash sample is exact:
        the tanh Jacobian does not depend on the parameters. The same number as
        :meth:`SDENormal.log_prob <sde_torchrl.modules.distribution.SDENormal.log_prob>` of ``sample``.

        Args:
            loc: controller mean, ``[*batch, A]``.
            features: exploration features, ``[*batch, S]``.
            sample: the pre-squash action that was taken, ``[*batch, A]``.

        Returns:
            Log-likelihood of shape ``[*batch]``.
        """
        return gaussian_log_prob(sample, loc, self.scale(features))

    def _check_shapes(self, loc: torch.Tensor, features: torch.Tensor) -> None:
        if loc.shape[-1] != self.action_dim:
            raise ValueError(
                f"{self.loc_key!r} has shape {tuple(loc.shape)}: expected [..., {self.action_dim}] "
                f"(action_dim={self.action_dim})"
            )
        if features.shape[-1] != self.feature_dim or features.shape[:-1] != loc.shape[:-1]:
            raise ValueError(
                f"{self.feature_key!r} has shape {tuple(features.shape)}: expected "
                f"{tuple(loc.shape[:-1]) + (self.feature_dim,)} ({self.loc_key!r} batch "
                f"{tuple(loc.shape[:-1])}, feature_dim={self.feature_dim})"
            )


__all__ = ["SDEParams", "expln", "expln_inverse", "sigma_from_param", "sigma_param_shape"]
