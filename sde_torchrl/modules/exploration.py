"""State-dependent exploration (SDE), paper section 3: its parameters and the explorer.

The explorer adds ``ε̂(x; Θ̂) = Θ̂ x`` to the controller's mean (17)-(19), with
``Θ̂_ji = σ̂_ji ξ_ji`` and ``ξ ~ N(0, 1)`` kept in the tensordict under a public key, redrawn at
episode boundaries (SDE), at every step (REX, the paper's random-exploration baseline) or every
``n`` steps. ``σ̂ = expln(p)`` (23) keeps the standard deviations positive; i.i.d. Gaussian noise
with its own ``σ = expln(q)`` can be added on top (22).

:class:`SDESigma` holds those parameters and the per-step Gaussian they define; it is shared by
:class:`StateDependentExplorer` (which samples by itself, for the episodic estimators) and
:class:`~sde_torchrl.modules.sde_actor.SDEParams` (which writes them for
:class:`~sde_torchrl.modules.distribution.SDENormal`, for TorchRL's losses). The maths of both lives in
:mod:`sde_torchrl.modules.distribution`.
"""

from __future__ import annotations

import warnings

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import nn
from torchrl.data import Composite, Unbounded
from torchrl.envs import Compose, TensorDictPrimer
from torchrl.envs.utils import ExplorationType, exploration_type

from sde_torchrl.modules.distribution import gaussian_log_prob, noise_matrix, sde_sample, sde_variance
from sde_torchrl.utils.checks import ArgumentError, one_of, positive_int
from sde_torchrl.utils.rng import RunStreams, draw_normal
from sde_torchrl.utils.shapes import align

SCHEDULES = ("episode", "step", "every_n")
SHARINGS = ("element", "action", "single")
_DETERMINISTIC = (ExplorationType.DETERMINISTIC, ExplorationType.MODE, ExplorationType.MEAN)


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


def deterministic_exploration() -> bool:
    """Whether TorchRL's exploration type asks for the mean action (``DETERMINISTIC``, ``MODE``
    or ``MEAN``): then the explorer adds no noise and draws nothing."""
    return exploration_type() in _DETERMINISTIC


def sigma_param_shape(sharing: str, action_dim: int, feature_dim: int) -> tuple[int, int]:
    """Shape of ``p`` (``σ̂ = expln(p)``) for a sharing mode (paper section 2.3, footnote 1).

    Args:
        sharing: one ``σ̂`` per matrix element (``"element"``), per action (``"action"``) or one
            for all (``"single"``).
        action_dim: ``A``.
        feature_dim: ``S``.

    Returns:
        ``(A, S)``, ``(A, 1)`` or ``(1, 1)``: broadcastable to the ``A × S`` matrix.

    Examples:
        >>> sigma_param_shape("action", 2, 3)
        (2, 1)
    """
    return {"element": (action_dim, feature_dim), "action": (action_dim, 1)}.get(sharing, (1, 1))


class SDESigma(TensorDictModuleBase):
    """The parameters of state-dependent exploration and the per-step Gaussian they define.

    Holds ``p`` with ``σ̂ = expln(p)`` (eqs. 23, 24), one per matrix element, per action or one
    for all (``sharing``), and, for eq. (22)'s i.i.d. Gaussian part, ``q`` with
    ``σ_gauss = expln(q)`` per action: parameters named ``sigma_param`` and ``gaussian_param``
    (buffers if not learned), stacked over ``runs`` along a leading dimension. Given the
    features ``x``, the action is Gaussian around the controller's mean with
    ``σ_j² = Σ_i (x_i σ̂_ji)² [+ σ_gauss_j²]`` (eq. 20): :meth:`scale` and :meth:`log_prob`.

    The base of :class:`StateDependentExplorer` and :class:`~sde_torchrl.modules.sde_actor.SDEParams`,
    which add a ``forward`` (and their keys): both explore with the same parameters, under the
    same names, through the same maths (:mod:`sde_torchrl.modules.distribution`).

    Args:
        action_dim: ``A``, size of the action.
        feature_dim: ``S``, size of the exploration features ``x``.
        schedule: when ``ξ`` is redrawn: ``"episode"`` (SDE), ``"step"`` (REX) or
            ``"every_n"`` (gSDE's sampling frequency).
        every_n: redraw period for ``schedule="every_n"``.
        sharing: one ``σ̂`` per matrix element (``"element"``, ``A×S``), per action
            (``"action"``, ``A``) or one for all (``"single"``) (paper section 2.3, footnote 1).
        init_param: initial ``p``; the paper starts at -2 (``σ̂ ≈ 0.135``).
        gaussian_init_param: initial ``q`` of eq. (22)'s i.i.d. Gaussian part, ``None`` for none.
        learn_sigma: ``p`` (and ``q``) as learnable parameters, or as fixed buffers.
        runs: independent runs stacked along a leading parameter dimension, or ``None`` for a
            single, unstacked learner.
        loc_key: the controller's mean.
        feature_key: the features ``x`` that ``Θ̂`` sees.

    Attributes:
        streams: per-run :class:`~sde_torchrl.utils.rng.RunStreams` for the noise draws when runs are
            stacked (the data's leading batch dimension); ``None``: torch's global generator.

    Raises:
        ArgumentError: for an option that is not allowed, named.

    Examples:
        >>> sigma = SDESigma(action_dim=2, feature_dim=3, sharing="action", runs=4)
        >>> sigma.sigma_param.shape, sigma.sde_sigma.shape
        (torch.Size([4, 2, 1]), torch.Size([4, 2, 3]))
        >>> sigma.scale(torch.ones(4, 10, 3)).shape  # eq. 20 per run, step and action
        torch.Size([4, 10, 2])
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
    ) -> None:
        super().__init__()
        self.action_dim = positive_int("action_dim", action_dim)
        self.feature_dim = positive_int("feature_dim", feature_dim)
        self.schedule = one_of("schedule", schedule, SCHEDULES)
        if schedule == "every_n":
            positive_int("every_n", every_n)
        elif every_n is not None:
            raise ArgumentError("every_n", every_n, "null unless schedule=every_n")
        self.every_n, self.sharing = every_n, one_of("sharing", sharing, SHARINGS)
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
        self.loc_key, self.feature_key = loc_key, feature_key
        self.in_keys, self.out_keys = [loc_key, feature_key], []

    def _register(self, name: str, value: torch.Tensor, learnable: bool) -> None:
        if learnable:
            self.register_parameter(name, nn.Parameter(value))
        else:
            self.register_buffer(name, value)

    @property
    def sde_sigma(self) -> torch.Tensor:
        """``σ̂ = expln(p)`` broadcast to the full ``[*runs, A, S]`` matrix (eq. 23)."""
        sigma = expln(self.sigma_param)
        return sigma.expand(*sigma.shape[:-2], self.action_dim, self.feature_dim)

    def exploration_scale(self) -> torch.Tensor:
        """Every ``σ̂`` element per run, ``[*runs, A·S]``: what ``metrics.csv`` reports as
        ``sigma_min`` / ``sigma_max`` (a collapsed exploration shows as ``σ̂ ≈ 0``)."""
        return self.sde_sigma.detach().flatten(-2)

    def gaussian_scale(self, batch_dims: int) -> torch.Tensor | None:
        """``σ_gauss = expln(q)`` (eqs. 22, 23) viewed to broadcast against ``[*batch, A]`` data
        with ``batch_dims`` batch dimensions (runs first), or ``None`` for pure SDE."""
        return align(expln(self.gaussian_param), self.run_dims, batch_dims) if self.has_gaussian else None

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


class StateDependentExplorer(SDESigma):
    """Adds state-dependent exploration ``Θ̂ x`` to a controller's mean (eqs. 17-24).

    Reads the controller's mean (``loc``), the exploration features ``x`` (by default the
    observation) and the standard-normal noise matrix ``ξ`` (``sde_noise``, shape ``[A, S]`` per
    batch element), and writes:

    * ``action``: ``squash(loc + (σ̂ ⊙ ξ) x [+ σ ε])``; ``tanh`` if ``squash`` is set;
    * ``action_sample``: the same before squashing (what the likelihood scores);
    * ``scale``: ``σ_j = sqrt(Σ_i (x_i σ̂_ji)² [+ σ_j²])`` (eq. 20, plus eq. 22's Gaussian part);
    * ``action_log_prob``: ``Σ_j log N(action_sample_j; loc_j, σ_j²)`` (eq. 13 with eq. 20);
    * ``sde_noise`` (and ``sde_age`` for ``every_n``): the noise to carry to the next step.

    ``ξ`` is redrawn, per batch element, where ``is_init`` is set (written by TorchRL's
    ``InitTracker`` at every full or partial reset) and, depending on ``schedule``:
    ``"episode"`` never again within the episode (SDE), ``"step"`` at every step (REX: the
    paper emulates random exploration this way), ``"every_n"`` every ``n`` steps (gSDE's
    sampling frequency). Where the noise is missing from the input it is drawn. The draws use
    torch's global generator, or per-run streams (``streams``, a
    :class:`~sde_torchrl.utils.rng.RunStreams` over the leading batch dimension) when runs are stacked.

    Under ``ExplorationType.DETERMINISTIC`` (or ``MODE``/``MEAN``) no noise is added: the action
    is ``squash(loc)``. The noise matrix still travels with the episode, untouched.

    Its parameters, :meth:`scale` and :meth:`log_prob` are :class:`SDESigma`'s, shared with
    :class:`~sde_torchrl.modules.sde_actor.SDEParams`, and its sample is
    :func:`~sde_torchrl.modules.distribution.sde_sample`: given the same ``ξ``, the action and its
    log-prob are those of :class:`~sde_torchrl.modules.distribution.SDENormal`. It samples by itself
    (what the episodic estimators and the fast rollout paths need); TorchRL's PPO, A2C and SAC
    losses need the distribution form, :func:`~sde_torchrl.modules.sde_actor.make_sde_actor`.

    Args:
        action_dim: ``A``, size of the action.
        feature_dim: ``S``, size of the exploration features ``x``.
        schedule: ``"episode"``, ``"step"`` or ``"every_n"``.
        every_n: redraw period for ``schedule="every_n"``.
        sharing: one ``σ̂`` per matrix element (``"element"``, ``A×S``), per action
            (``"action"``, ``A``) or one for all (``"single"``) (paper section 2.3, footnote 1).
        init_param: initial ``p`` with ``σ̂ = expln(p)``; the paper starts at -2 (σ̂ ≈ 0.135).
        gaussian_init_param: if given, adds i.i.d. Gaussian noise with learnable per-action
            ``σ = expln(q)`` starting at this ``q`` (eq. 22); ``None`` for pure SDE.
        learn_sigma: whether ``p`` (and ``q``) are learnable parameters or fixed buffers.
        squash: apply ``tanh`` to the action (the likelihood scores the pre-squash sample).
        runs: number of independent runs stacked along a leading parameter dimension, or
            ``None`` for a single, unstacked learner.
        feature_key: key of the features ``x`` that Θ̂ sees.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> explorer = StateDependentExplorer(action_dim=2, feature_dim=3)
        >>> td = TensorDict({"loc": torch.zeros(5, 2), "observation": torch.randn(5, 3)}, [5])
        >>> explorer(td)["action"].shape
        torch.Size([5, 2])
    """

    #: The tensordict keys it reads and writes (``feature_key`` is set per instance).
    loc_key, feature_key, noise_key, age_key, is_init_key = "loc", "observation", "sde_noise", "sde_age", "is_init"
    sample_key, scale_key, action_key, log_prob_key = "action_sample", "scale", "action", "action_log_prob"

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
        squash: bool = False,
        runs: int | None = None,
        feature_key: str = "observation",
    ) -> None:
        super().__init__(
            action_dim, feature_dim, schedule=schedule, every_n=every_n, sharing=sharing, init_param=init_param,
            gaussian_init_param=gaussian_init_param, learn_sigma=learn_sigma, runs=runs, loc_key=self.loc_key,
            feature_key=feature_key,
        )
        self.squash = squash
        self._warned_no_init = False
        self.in_keys = [self.loc_key, self.feature_key, self.noise_key, self.is_init_key]
        self.out_keys = [self.action_key, self.sample_key, self.scale_key, self.log_prob_key,
                         self.noise_key]
        if schedule == "every_n":
            self.in_keys.append(self.age_key)
            self.out_keys.append(self.age_key)

    def make_tensordict_primer(self) -> Compose:
        """Primer that gives every (partially) reset env a fresh noise matrix.

        Append it (with ``InitTracker``) to the env, or let TorchRL's
        ``Collector(auto_register_policy_transforms=True)`` do so.
        """
        primers = [TensorDictPrimer(
            Composite({self.noise_key: Unbounded(shape=(self.action_dim, self.feature_dim))}),
            random=True, expand_specs=True,
        )]
        if self.schedule == "every_n":
            primers.append(TensorDictPrimer(
                Composite({self.age_key: Unbounded(shape=(1,), dtype=torch.int64)}),
                default_value=0, expand_specs=True,
            ))
        return Compose(*primers)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        loc = tensordict.get(self.loc_key)
        features = tensordict.get(self.feature_key).to(loc.dtype)
        is_init = tensordict.get(self.is_init_key, None)
        previous = tensordict.get(self.noise_key, None)
        if previous is not None and is_init is None and self.schedule != "step" and not self._warned_no_init:
            self._warned_no_init = True
            warnings.warn(
                f"StateDependentExplorer: the input carries {self.noise_key!r} but no {self.is_init_key!r}, so "
                "the noise matrix is never redrawn when an episode starts; add torchrl.envs.InitTracker() "
                f"and explorer.make_tensordict_primer() to the env, or use Collector(..., "
                "auto_register_policy_transforms=True)", UserWarning, stacklevel=2)
        sample, noise, age = self.act(loc, features, previous, is_init, tensordict.get(self.age_key, None))
        if noise is not None:
            tensordict.set(self.noise_key, noise)
        if age is not None:
            tensordict.set(self.age_key, age)
        tensordict.set(self.sample_key, sample)
        tensordict.set(self.action_key, torch.tanh(sample) if self.squash else sample)
        scale = self.scale(features)
        tensordict.set(self.scale_key, scale)
        tensordict.set(self.log_prob_key, gaussian_log_prob(sample, loc, scale))
        return tensordict

    def act(
        self, loc: torch.Tensor, features: torch.Tensor, noise: torch.Tensor | None = None,
        is_init: torch.Tensor | None = None, age: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """The tensor-level step behind :meth:`forward`: schedule the noise, then perturb.

        Args:
            loc: controller mean ``[*batch, A]``.
            features: exploration features ``[*batch, S]``.
            noise: the previous step's ``ξ`` ``[*batch, A, S]``, or ``None`` (then drawn).
            is_init: ``[*batch, 1]`` (or ``[*batch]``) flags of episodes that just started.
            age: steps since the last draw (``every_n`` only).

        Returns:
            ``(sample, noise, age)``: the pre-squash action and the state to carry. Under
            deterministic exploration the sample is ``loc`` and nothing is drawn.
        """
        self._check_shapes(loc, features)
        if deterministic_exploration():
            # No draw at all: evaluating a policy must not shift the exploration stream.
            return loc, noise, age
        noise, age = self._next_noise(noise, is_init, age, loc.shape[:-1])
        return self.perturb(loc, features, noise), noise, age

    def perturb(self, loc: torch.Tensor, features: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """``u = f(x) + Θ̂ x (+ ε)`` with ``Θ̂ = σ̂ ⊙ ξ`` (eqs. 17-19, 22), before squashing."""
        sigma_hat = align(self.sde_sigma, self.run_dims, noise.dim() - 2)
        gaussian_noise = draw_normal(loc.shape, self.streams) if self.has_gaussian else None
        return sde_sample(loc, sigma_hat, noise, features, self.gaussian_scale(loc.dim() - 1), gaussian_noise)

    def noise_matrix(self, noise: torch.Tensor) -> torch.Tensor:
        """``Θ̂ = σ̂ ⊙ ξ`` (eq. 18) for noise ``ξ`` shaped ``[*batch, A, S]`` (runs first)."""
        return noise_matrix(align(self.sde_sigma, self.run_dims, noise.dim() - 2), noise)

    def _next_noise(
        self, previous: torch.Tensor | None, is_init: torch.Tensor | None,
        age: torch.Tensor | None, batch: torch.Size,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The noise ξ for this step: carried over, or fresh where the schedule says so."""
        fresh = draw_normal((*batch, self.action_dim, self.feature_dim), self.streams)
        if previous is None or self.schedule == "step":
            return fresh, (torch.ones(*batch, 1, dtype=torch.int64) if self.schedule == "every_n" else None)
        redraw = (torch.zeros(*batch, 1, dtype=torch.bool) if is_init is None
                  else is_init.reshape(*batch, 1))
        if self.schedule == "every_n":
            age = torch.zeros(*batch, 1, dtype=torch.int64) if age is None else age.reshape(*batch, 1)
            age = torch.where(redraw, 0, age)
            redraw = age % self.every_n == 0
            age = age + 1
        return torch.where(redraw.unsqueeze(-1), fresh, previous), age
