"""The policy's schemas: the ``actor`` group (the controller giving the action's mean) and the
``explorer`` group (the noise around it: SDE, PGPE's parameter draws, plain Gaussian).

Examples:
    >>> LinearActorConf().bias, MLPActorConf().bias
    (False, True)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, List, Optional

from sde_torchrl.config.schemas.frozen import Frozen
from sde_torchrl.utils.checks import ArgumentError, float32_number, is_finite_number, is_int, noise_schedule, one_of
from sde_torchrl.utils.options import ACTIVATIONS, SHARINGS, SIGMA_TRANSFORMS

# ``typing`` generics, not ``list[int]`` or ``X | None``: OmegaConf reads these annotations at runtime.
# ruff: noqa: UP006, UP007, UP035, UP045


@dataclass
class LinearActorConf(Frozen, schema="actor/linear"):
    """``actor=linear``: ``u = Θ x (+ b)``; the paper's controllers have no bias.

    Attributes:
        bias: learn ``b``.
        init: every parameter's start value, or ``[low, high]`` for uniform draws.

    Examples:
        >>> LinearActorConf(init=[-0.1, 0.1]).init
        [-0.1, 0.1]
    """

    _target_: str = "sde_torchrl.modules.actors.LinearActor"
    bias: bool = False
    init: Any = -2.0

    def __post_init__(self) -> None:
        _check_init(self.init)


@dataclass
class MLPActorConf(Frozen, schema="actor/mlp"):
    """``actor=mlp``: a small multi-layer perceptron; by default the paper's (section 4.1,
    "Parameter dimensionality"): 3 sigmoid hidden units, bias units, ``θ_i ~ U[-1, 0)``.

    Attributes:
        hidden: hidden layer sizes.
        activation: of the hidden layers.
        bias: bias units into the hidden and output layers.
        init: every parameter's start value, or ``[low, high]`` for uniform draws.

    Examples:
        >>> MLPActorConf().hidden
        [3]
    """

    _target_: str = "sde_torchrl.modules.actors.MLPActor"
    hidden: List[int] = field(default_factory=lambda: [3])
    activation: str = "sigmoid"
    bias: bool = True
    init: Any = field(default_factory=lambda: [-1.0, 0.0])

    def __post_init__(self) -> None:
        _check_init(self.init)
        if not all(is_int(size) and size >= 1 for size in self.hidden):
            raise ArgumentError("actor.hidden", self.hidden, "a list of positive integers")
        one_of("actor.activation", self.activation, ACTIVATIONS)


def _check_init(init: Any) -> None:
    allowed = "a number, or [low, high] with low < high"
    if isinstance(init, (list, tuple)):
        if len(init) != 2 or not all(is_finite_number(v) for v in init) or not init[0] < init[1]:
            raise ArgumentError("actor.init", init, allowed)
    elif init is not None and not is_finite_number(init):
        raise ArgumentError("actor.init", init, allowed)


@dataclass
class ExplorerConf(Frozen, schema="explorer/sde"):
    """``explorer=sde|rex|every_n|sde_gauss``: the state-dependent explorer (paper section 3).

    Attributes:
        schedule: when ``Θ̂`` is redrawn: every ``episode`` (SDE), every ``step`` (REX, emulated
            as in the paper) or ``every_n`` steps, always at a reset; or as SB3's
            ``sde_sample_freq`` counts, through resets: ``every_n_steps`` of a rollout or once per
            ``rollout`` (:class:`~sde_torchrl.modules.noise.SDENoisePrimer`).
        every_n: the period for ``schedule=every_n`` or ``every_n_steps``, else ``null``.
        rollout_steps: steps per rollout for ``every_n_steps`` and ``rollout`` (``null``: until
            an explicit redraw or a fresh reset); ``null`` for the other schedules.
        sharing: one ``σ̂`` per matrix ``element`` (``A×S``), per ``action`` (``A``), a
            ``single`` one, or one per ``feature`` shared over the actions (SB3's ``full_std=False``).
        sigma_transform: ``σ̂ = expln(p)`` (eq. 23) or ``exp`` (SB3's ``use_expln=False``).
        init_param: ``σ̂ = expln(init_param)`` at the start (``-2``: ``σ̂ ≈ 0.135``).
        gaussian_init_param: set for eq. 22's extra i.i.d. Gaussian noise, ``σ = expln(q)``.
        learn_sigma: learn ``σ̂`` (else it stays at its start value).
        squash: tanh on the action; the likelihood scores the pre-squash sample.

    Examples:
        >>> ExplorerConf(schedule="every_n", every_n=5).every_n
        5
    """

    _target_: str = "sde_torchrl.modules.sde.SDEParams"
    schedule: str = "episode"
    every_n: Optional[int] = None
    rollout_steps: Optional[int] = None
    sharing: str = "element"
    sigma_transform: str = "expln"
    init_param: float = -2.0
    gaussian_init_param: Optional[float] = None
    learn_sigma: bool = True
    squash: bool = False

    def __post_init__(self) -> None:
        noise_schedule(self.schedule, self.every_n, "explorer.", rollout_steps=self.rollout_steps)
        one_of("explorer.sharing", self.sharing, SHARINGS)
        one_of("explorer.sigma_transform", self.sigma_transform, SIGMA_TRANSFORMS)
        float32_number("explorer.init_param", self.init_param)
        if self.gaussian_init_param is not None:
            float32_number("explorer.gaussian_init_param", self.gaussian_init_param)


@dataclass
class PGPEExplorerConf(Frozen, schema="explorer/pgpe"):
    """``explorer=pgpe``: PGPE's parameter sampling, ``θ ~ N(μ, diag(σ²))`` once per episode
    (Sehnke et al. 2010; :class:`~sde_torchrl.modules.pgpe.ParameterExplorer`), with ``estimator=pgpe``.

    Attributes:
        symmetric: symmetric sampling ``θ± = μ ± ε`` over pairs of episodes (section 2.3);
            ``episodes_per_update`` must then be even.
        init_param: ``σ`` starts at ``expln(init_param)`` per parameter, SDE's ``σ̂₀`` for the
            same value (``-2``: ≈ 0.135).
        learn_sigma: learn ``σ`` (else it stays at its start value).
        squash: tanh on the action.
        draws_actor_parameters: the explorer draws the actor's own parameters (one ``σ`` per
            actor parameter); a class attribute that the memory estimate
            (:func:`~sde_torchrl.jobs.resources.policy_sizes`) reads, ``False`` for any other explorer.

    Examples:
        >>> PGPEExplorerConf().symmetric, PGPEExplorerConf.draws_actor_parameters
        (True, True)
    """

    draws_actor_parameters: ClassVar[bool] = True
    _target_: str = "sde_torchrl.modules.pgpe.ParameterExplorer"
    symmetric: bool = True
    init_param: float = -2.0
    learn_sigma: bool = True
    squash: bool = False

    def __post_init__(self) -> None:
        float32_number("explorer.init_param", self.init_param)


@dataclass
class GaussianExplorerConf(Frozen, schema="explorer/gaussian"):
    """``explorer=gaussian``: the plain-Gaussian baseline of ``algorithm=ppo|a2c``: i.i.d. noise with
    a learned state-independent standard deviation per action, ``σ = exp(init_param)`` at the
    start (SB3's PPO and A2C without ``use_sde``; :mod:`sde_torchrl.modules.gaussian`).

    Attributes:
        init_param: the initial ``log σ`` (SB3's ``log_std_init``; ``-2``: ``σ ≈ 0.135``).
        learn_sigma: learn ``σ`` (else it stays at its start value).
        squash: tanh on the action (TorchRL's ``TanhNormal``).

    Examples:
        >>> GaussianExplorerConf().init_param
        -2.0
    """

    _target_: str = "sde_torchrl.modules.gaussian.GaussianScale"
    init_param: float = -2.0
    learn_sigma: bool = True
    squash: bool = False

    def __post_init__(self) -> None:
        float32_number("explorer.init_param", self.init_param)

