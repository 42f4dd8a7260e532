"""Config schemas: the single source of truth for what a config may hold.

Every config group option is backed by a dataclass registered in Hydra's ``ConfigStore``
under ``schema/<group>/<option>`` (the YAML files list it first in their defaults and hold only
what differs from it), and the top-level config by ``schema/config``. Hydra then rejects unknown
keys and wrong types while composing; :func:`validate`
converts the composed config once into these dataclasses, whose ``__post_init__`` checks the
values (positive counts, allowed strings, options that only make sense together) with :mod:`sde_torchrl.utils.checks`.
Every failure is turned into one line by :func:`describe_error`: ``<key>=<value>: <what is
allowed>``.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any, List, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf

from sde_torchrl.jobs.resources import check_memory, launcher_request
from sde_torchrl.trainers.settings import TrainingSettings
from sde_torchrl.utils.checks import (
    ArgumentError,
    finite,
    float32_number,
    fraction,
    is_finite_number,
    is_int,
    noise_schedule,
    non_negative_int,
    one_of,
    positive_int,
    show,
)
from sde_torchrl.utils.devices import check_device_name
from sde_torchrl.utils.options import (
    ACTIVATIONS,
    EPISODE_RETURNS,
    LR_SCHEDULES,
    NORMALIZATIONS,
    REWARD_STATES,
    ROLLOUT_SCHEDULES,
    SHARINGS,
    SIGMA_TRANSFORMS,
)

# ``typing`` generics, not ``list[int]`` or ``X | None``: OmegaConf reads these annotations at runtime.
# ruff: noqa: UP006, UP007, UP035, UP045


# The allowed strings live in sde_torchrl.utils.options, beside no torch. Strings checked by the
# schemas, not Enums: Hydra would reject an unknown Enum value while composing, which in a multirun
# stops the whole sweep instead of failing that one job (with its error.txt). The arm names are
# kept beside the models' data, which imports pybullet on use: a test checks the two agree.
ARM_MODELS = ("pybrain", "cup", "pybrain_held")


# ------------------------------------------------------------------------------ schemas


@dataclass
class MinimizeEnvConf:
    """``env=minimize``: the function-minimisation task (paper section 4.1) as the authors' PyBrain
    code runs it: ``x_{t+1} = x_t + s u_t + N(0, σ_noise²)``, ``r_t = -‖x_t + s u_t‖²``.

    Attributes:
        episode_length: ``EL``, steps per episode.
        dim: dimension of the state and action.
        x0: start state, a scalar or a ``dim``-vector (not given by the paper; 2 in the
            authors' code).
        x0_spread: half-width of a uniform jitter around ``x0``.
        step_size: ``s``.
        noise_std: ``σ_noise``.
        reward_state: ``noise_free`` scores ``g(x_t + s u_t)`` (the authors' code), ``noisy``
            scores the noisy next state ``g(x_{t+1})``.

    Examples:
        >>> MinimizeEnvConf(episode_length=30).dim
        1
    """

    _target_: str = "sde_torchrl.envs.make_minimize_env"
    episode_length: int = 15
    dim: int = 1
    x0: Any = 2.0
    x0_spread: float = 0.0
    step_size: float = 0.1
    noise_std: float = 0.5
    reward_state: str = "noise_free"

    def __post_init__(self) -> None:
        positive_int("env.episode_length", self.episode_length)
        positive_int("env.dim", self.dim)
        finite("env.x0_spread", self.x0_spread, minimum=0)
        finite("env.noise_std", self.noise_std, minimum=0)
        finite("env.step_size", self.step_size)
        one_of("env.reward_state", self.reward_state, REWARD_STATES)


@dataclass
class BallCatchEnvConf:
    """``env=ballcatch``: an arm with a hand catches a ball released above the palm (pybullet,
    paper section 4.2).

    Attributes:
        episode_length: steps of 0.01 s per episode.
        jitter: half-width of the uniform horizontal release offset, in ``[0, 0.4]``.
        model: the arm, ``pybrain`` (after PyBrain's ``arm.xode``, the authors' arm), ``cup``, or the
            diagnostic ``pybrain_held`` (the pybrain arm with shoulder, elbow and wrist held).
        observation: ``raw`` (the ball position, the paper's) or ``scaled`` (mapped onto
            [-1, 1] over the arm's workspace, a constant feature 1 appended).

    Examples:
        >>> BallCatchEnvConf().episode_length
        500
        >>> BallCatchEnvConf().model
        'pybrain'
    """

    _target_: str = "sde_torchrl.envs.ballcatch.batched.make_ballcatch_env"
    episode_length: int = 500
    jitter: float = 0.05
    model: str = "pybrain"
    observation: str = "raw"

    def __post_init__(self) -> None:
        positive_int("env.episode_length", self.episode_length)
        one_of("env.observation", self.observation, ("raw", "scaled"))
        if not is_finite_number(self.jitter) or not 0 <= self.jitter <= 0.4:
            raise ArgumentError("env.jitter", self.jitter, "a number in [0, 0.4]")
        one_of("env.model", self.model, ARM_MODELS)


@dataclass
class GymEnvConf:
    """``env=gym``: any gymnasium continuous-control env, through TorchRL's ``GymEnv``
    (``env=gym env.id=Pendulum-v1``; README, "Any gymnasium env").

    Attributes:
        id: a registered gymnasium id whose env has a continuous (1-D ``Box``) action space and a
            flat ``Box`` observation, checked here by making the env once (a few ms for the
            classic-control envs); ``"module:Env-v0"`` imports ``module`` first and is checked
            when built.
        episode_length: ``T``, at most the env's time limit (``gym_kwargs.max_episode_steps``
            raises it); episodes that end earlier are held absorbing until ``T``.
        normalize_obs: ``null``, ``bounds`` (a bounded space mapped to ``[-1, 1]``) or ``stats``
            (mean and standard deviation of random steps).
        norm_init_steps: random steps for ``normalize_obs=stats``.
        constant_feature: append 1 to the explorer's features (noise where the observation is ~0).
        gym_kwargs: passed to ``gymnasium.make``; holds ``max_episode_steps`` (``null``: the env's
            own time limit), so ``env.gym_kwargs.max_episode_steps=500`` needs no ``+`` (other
            keys do: ``+env.gym_kwargs.KEY=VALUE``).
        reset_options: passed to every ``reset(options=...)``, e.g. ``{x_init: 0.3, y_init: 0.3}``.

    Examples:
        >>> GymEnvConf(normalize_obs="stats").norm_init_steps
        1000
    """

    _target_: str = "sde_torchrl.envs.gym.make_gym_env"
    id: str = "Pendulum-v1"
    episode_length: int = 200
    normalize_obs: Optional[str] = None
    norm_init_steps: int = 1000
    constant_feature: bool = False
    gym_kwargs: Any = field(default_factory=lambda: {"max_episode_steps": None})
    reset_options: Any = None

    def __post_init__(self) -> None:
        positive_int("env.episode_length", self.episode_length)
        if self.normalize_obs is not None and self.normalize_obs not in NORMALIZATIONS:
            raise ArgumentError("env.normalize_obs", self.normalize_obs, f"null or one of {', '.join(NORMALIZATIONS)}")
        positive_int("env.norm_init_steps", self.norm_init_steps)
        _check_gym_kwargs(self.gym_kwargs)
        _check_gym_env(self.id, self.episode_length, self.gym_kwargs or {})


def _check_gym_kwargs(gym_kwargs: Any) -> None:
    if gym_kwargs is not None and not isinstance(gym_kwargs, Mapping):
        raise ArgumentError("env.gym_kwargs", gym_kwargs, "null or a mapping of keyword arguments for gymnasium.make")
    steps = (gym_kwargs or {}).get("max_episode_steps")
    if steps is not None and (not is_int(steps) or steps < 1):
        raise ArgumentError("env.gym_kwargs.max_episode_steps", steps,
                            "a positive integer, or null (the env's own time limit)")


def _check_gym_env(env_id: Any, episode_length: int, gym_kwargs: Mapping[str, Any]) -> None:
    """A registered id whose env SDE can drive (spaces, time limit), made once to find out."""
    allowed = "a registered gymnasium env id such as Pendulum-v1"
    if not isinstance(env_id, str) or not env_id:
        raise ArgumentError("env.id", env_id, allowed)
    if ":" in env_id:  # "module:Env-v0" registers on import: checked when built
        return
    import gymnasium

    from sde_torchrl.envs.gym_checks import check_gym_env

    if env_id not in gymnasium.envs.registry:
        close = sorted(k for k in gymnasium.envs.registry if k.lower().startswith(env_id.lower()[:4]))
        hint = f" (close: {', '.join(close[:5])})" if close else ""
        raise ArgumentError("env.id", env_id, allowed + hint)
    check_gym_env(env_id, episode_length, gym_kwargs)


@dataclass
class LinearActorConf:
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
class MLPActorConf:
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
class ExplorerConf:
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
class PGPEExplorerConf:
    """``explorer=pgpe``: PGPE's parameter sampling, ``θ ~ N(μ, diag(σ²))`` once per episode
    (Sehnke et al. 2010; :class:`~sde_torchrl.modules.pgpe.ParameterExplorer`), with ``estimator=pgpe``.

    Attributes:
        symmetric: symmetric sampling ``θ± = μ ± ε`` over pairs of episodes (section 2.3);
            ``episodes_per_update`` must then be even.
        init_param: ``σ`` starts at ``expln(init_param)`` per parameter, SDE's ``σ̂₀`` for the
            same value (``-2``: ≈ 0.135).
        learn_sigma: learn ``σ`` (else it stays at its start value).
        squash: tanh on the action.

    Examples:
        >>> PGPEExplorerConf().symmetric
        True
    """

    _target_: str = "sde_torchrl.modules.pgpe.ParameterExplorer"
    symmetric: bool = True
    init_param: float = -2.0
    learn_sigma: bool = True
    squash: bool = False

    def __post_init__(self) -> None:
        float32_number("explorer.init_param", self.init_param)


@dataclass
class GaussianExplorerConf:
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


@dataclass
class OnPolicyConf:
    """What ``algorithm=ppo`` and ``algorithm=a2c`` share: actor-critic training on ``env=gym``
    (:mod:`sde_torchrl.trainers.onpolicy`), exploring with an SDE explorer (``sde``, ``gsde``,
    ...; features from the actor's last hidden layer) or ``explorer=gaussian``. ``lr`` and
    ``optimizer`` are the top level's; ``updates`` counts iterations of ``n_envs × n_steps`` env
    steps.

    Attributes:
        n_envs: envs stepped side by side.
        n_steps: steps per env and update (rollout length).
        gamma: discount.
        gae_lambda: GAE's ``λ``.
        ent_coef: weight of the entropy bonus.
        vf_coef: weight of the critic's loss.
        max_grad_norm: bound on the gradient norm; ``null``: not clipped.
        normalize_advantage: standardise the advantages (per minibatch).
        normalize: SB3's ``VecNormalize``: running observation and reward normalisation
            (:mod:`sde_torchrl.envs.normalize`).
        time_feature: append ``1 - t / episode_length`` to the observation (sb3-contrib's
            ``TimeFeatureWrapper``, which rl-zoo puts around the Bullet envs for A2C).
        critic_hidden: the critic's hidden layers; ``null``: the actor's (``actor.hidden``).

    Examples:
        >>> OnPolicyConf().n_envs
        1
    """

    n_envs: int = 1
    n_steps: int = 2048
    gamma: float = 0.99
    gae_lambda: float = 0.95
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: Optional[float] = 0.5
    normalize_advantage: bool = True
    normalize: bool = False
    time_feature: bool = False
    critic_hidden: Optional[List[int]] = None

    def __post_init__(self) -> None:
        for name in ("n_envs", "n_steps"):
            positive_int(f"algorithm.{name}", getattr(self, name))
        for name in ("gamma", "gae_lambda"):
            fraction(f"algorithm.{name}", getattr(self, name))
        for name in ("ent_coef", "vf_coef"):
            finite(f"algorithm.{name}", getattr(self, name), minimum=0)
        if self.max_grad_norm is not None:
            finite("algorithm.max_grad_norm", self.max_grad_norm, minimum=0, strict=True)
        if self.critic_hidden is not None and not all(is_int(size) and size >= 1 for size in self.critic_hidden):
            raise ArgumentError("algorithm.critic_hidden", self.critic_hidden,
                                "null (the actor's hidden layers) or a list of positive integers")


@dataclass
class PPOConf(OnPolicyConf):
    """``algorithm=ppo``: Proximal Policy Optimization with TorchRL's ``ClipPPOLoss`` and ``GAE``
    (:mod:`sde_torchrl.trainers.ppo`); the defaults are Stable-Baselines3's ``PPO`` defaults. The
    shared options: :class:`OnPolicyConf`.

    Attributes:
        batch_size: steps per minibatch, at most ``n_envs × n_steps``.
        n_epochs: passes over each rollout.
        clip_range: PPO's clipping ``ε``.
        clip_range_schedule: ``ε`` over updates, as ``optimizer.lr_schedule`` the rate:
            ``constant``, or ``linear`` decay to 0 (rl-zoo's ``lin_0.4``).

    Examples:
        >>> PPOConf().n_steps, PPOConf().batch_size
        (2048, 64)
    """

    batch_size: int = 64
    n_epochs: int = 10
    clip_range: float = 0.2
    clip_range_schedule: str = "constant"

    def __post_init__(self) -> None:
        super().__post_init__()
        one_of("algorithm.clip_range_schedule", self.clip_range_schedule, ("constant", "linear"))
        for name in ("batch_size", "n_epochs"):
            positive_int(f"algorithm.{name}", getattr(self, name))
        if self.batch_size > self.n_envs * self.n_steps:
            raise ArgumentError("algorithm.batch_size", self.batch_size,
                                f"at most algorithm.n_envs × algorithm.n_steps = {self.n_envs * self.n_steps} "
                                "(the steps of one rollout)")
        finite("algorithm.clip_range", self.clip_range, minimum=0, strict=True)


@dataclass
class A2CConf(OnPolicyConf):
    """``algorithm=a2c``: Advantage Actor-Critic with TorchRL's ``A2CLoss`` and ``GAE``
    (:mod:`sde_torchrl.trainers.a2c`): one gradient step per rollout; the defaults are
    Stable-Baselines3's ``A2C`` defaults (with ``optimizer=rmsprop`` its optimiser). The shared
    options: :class:`OnPolicyConf`.

    Examples:
        >>> A2CConf().n_steps, A2CConf().gae_lambda, A2CConf().normalize_advantage
        (5, 1.0, False)
    """

    n_steps: int = 5
    gae_lambda: float = 1.0
    normalize_advantage: bool = False


@dataclass
class SACConf:
    """``algorithm=sac``: Soft Actor-Critic with TorchRL's ``SACLoss`` and ``ReplayBuffer`` on one
    gymnasium env (:mod:`sde_torchrl.trainers.offpolicy`, :mod:`sde_torchrl.trainers.sac`); the
    defaults are Stable-Baselines3's ``SAC`` defaults. ``lr`` and ``optimizer`` (Adam) are the top
    level's; ``updates`` counts rows of ``metrics.csv``, each ``rounds_per_update × train_freq``
    env steps. The actor is tanh-squashed (``explorer.squash`` must be true).

    Attributes:
        buffer_size: transitions the replay buffer keeps.
        batch_size: transitions per minibatch.
        learning_starts: env steps of uniform random actions before the first gradient step, a
            multiple of ``train_freq``.
        train_freq: env steps collected per round.
        gradient_steps: gradient steps after each round.
        gamma: discount.
        tau: the target critics' Polyak coefficient.
        ent_coef: the entropy coefficient: ``auto`` (learned, from 1, target entropy ``-dim(A)``)
            or a fixed number > 0.
        rounds_per_update: rounds per update (a row of ``metrics.csv``, a checkpoint boundary).
        time_feature: append ``1 - t / episode_length`` to the observation (sb3-contrib's
            ``TimeFeatureWrapper``).

    Examples:
        >>> SACConf().train_freq, SACConf().ent_coef
        (1, 'auto')
    """

    buffer_size: int = 1_000_000
    batch_size: int = 256
    learning_starts: int = 100
    train_freq: int = 1
    gradient_steps: int = 1
    gamma: float = 0.99
    tau: float = 0.005
    ent_coef: Any = "auto"
    rounds_per_update: int = 1
    time_feature: bool = False

    def __post_init__(self) -> None:
        for name in ("buffer_size", "batch_size", "train_freq", "gradient_steps", "rounds_per_update"):
            positive_int(f"algorithm.{name}", getattr(self, name))
        non_negative_int("algorithm.learning_starts", self.learning_starts)
        if self.learning_starts % self.train_freq:
            raise ArgumentError("algorithm.learning_starts", self.learning_starts,
                                f"a multiple of algorithm.train_freq ({self.train_freq}): the warm-up ends with a "
                                "round of collection")
        fraction("algorithm.gamma", self.gamma)
        fraction("algorithm.tau", self.tau)
        if self.ent_coef != "auto" and not (is_finite_number(self.ent_coef) and self.ent_coef > 0):
            raise ArgumentError("algorithm.ent_coef", self.ent_coef, "auto or a finite number > 0")


@dataclass
class EstimatorConf:
    """``estimator=reinforce|enac|gpomdp|pgpe``: episodic REINFORCE with the optimal per-parameter
    baseline, the Episodic Natural Actor-Critic (least squares on ``[ψ, 1]``), GPOMDP (each
    reward credited to the actions before it, with the time-dependent optimal baseline), or PGPE
    (the likelihood-ratio gradient of ``explorer=pgpe``'s parameter distribution, with the batch's
    mean return as baseline; :class:`~sde_torchrl.objectives.pgpe.PGPEEstimator`).

    Attributes:
        max_grad_norm: bound on each run's gradient norm; ``null``: plain ascent (eq. 1).
        max_grad_entry: the authors' rescale: a run's gradient whose largest (signed) entry
            exceeds this is scaled so that the entry equals it (1000 in their code); ``null``: off.
        episode_return: ``mean`` (the paper's text, section 2.1) or ``sum`` (the authors' code) of
            an episode's rewards; used by the estimator and every reported return.
        variance_weighted: the authors' "auto-alpha" scores: each action's log-likelihood
            weighted by its own variance ``σ_j²`` (held constant) before differentiating; for
            PGPE, Sehnke et al.'s step sizes ``α_i = α σ_i²``.

    Examples:
        >>> EstimatorConf(max_grad_norm=100.0).max_grad_norm
        100.0
    """

    _target_: str = "sde_torchrl.objectives.estimators.ReinforceEstimator"
    max_grad_norm: Optional[float] = None
    max_grad_entry: Optional[float] = None
    episode_return: str = "mean"
    variance_weighted: bool = False

    def __post_init__(self) -> None:
        for key in ("max_grad_norm", "max_grad_entry"):
            bound = getattr(self, key)
            if bound is not None and (not is_finite_number(bound) or bound <= 0):
                raise ArgumentError(f"estimator.{key}", bound, "a number > 0, or null (no bound)")
        one_of("estimator.episode_return", self.episode_return, EPISODE_RETURNS)


@dataclass
class SGDOptimizerConf:
    """``optimizer=sgd|momentum``: ``torch.optim.SGD`` on the policy gradient, with ``α = lr``.
    Without momentum it is the paper's plain ascent ``θ ← θ + α g`` (eq. 1); with momentum ``β``
    torch's heavy ball ``v ← β v + g``, ``θ ← θ + α v`` (steps ``1 / (1 - β)`` times longer once
    the gradients agree).

    Attributes:
        momentum: ``β`` in ``[0, 1)``; 0 is eq. 1.
        nesterov: Nesterov's variant (needs ``momentum > 0``).
        lr_schedule: the rate over updates: ``constant``, ``linear`` or ``cosine`` decay
            (:func:`sde_torchrl.trainers.optim.lr_factor`).
        final_lr_fraction: the factor on ``lr`` that a decay heads for, in ``[0, 1]``.

    Examples:
        >>> SGDOptimizerConf(momentum=0.9).lr_schedule
        'constant'
    """

    _target_: str = "torch.optim.SGD"
    momentum: float = 0.0
    nesterov: bool = False
    lr_schedule: str = "constant"
    final_lr_fraction: float = 0.0

    def __post_init__(self) -> None:
        fraction("optimizer.momentum", self.momentum, below_one=True)
        if self.nesterov and self.momentum == 0:
            raise ArgumentError("optimizer.nesterov", True, "false unless optimizer.momentum > 0")
        _check_schedule(self)


@dataclass
class AdamOptimizerConf:
    """``optimizer=adam``: ``torch.optim.Adam`` on the policy gradient, with ``α = lr``: a step
    of about ``α`` per parameter whatever the gradient's scale (sums or means of rewards alike).

    Attributes:
        betas: the decay rates of the first and second moment estimates, each in ``[0, 1)``.
        eps: added to the root of the second moment, ``> 0``.
        lr_schedule: the rate over updates: ``constant``, ``linear`` or ``cosine`` decay.
        final_lr_fraction: the factor on ``lr`` that a decay heads for, in ``[0, 1]``.

    Examples:
        >>> AdamOptimizerConf().betas
        [0.9, 0.999]
    """

    _target_: str = "torch.optim.Adam"
    betas: List[float] = field(default_factory=lambda: [0.9, 0.999])
    eps: float = 1e-8
    lr_schedule: str = "constant"
    final_lr_fraction: float = 0.0

    def __post_init__(self) -> None:
        if len(self.betas) != 2:
            raise ArgumentError("optimizer.betas", list(self.betas), "two numbers in [0, 1)")
        for beta in self.betas:
            fraction("optimizer.betas", beta, below_one=True)
        finite("optimizer.eps", self.eps, minimum=0, strict=True)
        _check_schedule(self)


@dataclass
class RMSpropOptimizerConf:
    """``optimizer=rmsprop``: ``torch.optim.RMSprop`` with ``α = lr`` (torch's defaults; SB3's
    A2C takes it with ``eps=1e-5``).

    Attributes:
        alpha: the decay rate of the squared-gradient average, in ``[0, 1)``.
        eps: added to its root, ``> 0``.
        lr_schedule: the rate over updates: ``constant``, ``linear`` or ``cosine`` decay.
        final_lr_fraction: the factor on ``lr`` that a decay heads for, in ``[0, 1]``.

    Examples:
        >>> RMSpropOptimizerConf().alpha
        0.99
    """

    _target_: str = "torch.optim.RMSprop"
    alpha: float = 0.99
    eps: float = 1e-8
    lr_schedule: str = "constant"
    final_lr_fraction: float = 0.0

    def __post_init__(self) -> None:
        fraction("optimizer.alpha", self.alpha, below_one=True)
        finite("optimizer.eps", self.eps, minimum=0, strict=True)
        _check_schedule(self)


def _check_schedule(conf: Any) -> None:
    one_of("optimizer.lr_schedule", conf.lr_schedule, LR_SCHEDULES)
    fraction("optimizer.final_lr_fraction", conf.final_lr_fraction)


@dataclass
class LoggerConf:
    """What every ``logger`` option has: TorchRL's logger class and the folder it writes into,
    ``<run dir>/<exp_name>``, which must stay inside the run directory.

    Examples:
        >>> try:
        ...     LoggerConf(exp_name="../x")
        ... except ArgumentError as error:
        ...     print(str(error).split(":")[0])
        logger.exp_name=../x
    """

    _target_: str = "torchrl.record.loggers.csv.CSVLogger"
    exp_name: str = "sde_torchrl"

    def __post_init__(self) -> None:
        _check_exp_name(self.exp_name)


@dataclass
class CSVLoggerConf(LoggerConf):
    """``logger=csv``: TorchRL's ``CSVLogger``, run-averaged curves under the run directory.

    Examples:
        >>> CSVLoggerConf().exp_name
        'sde_torchrl'
    """


@dataclass
class TensorboardLoggerConf(LoggerConf):
    """``logger=tensorboard``: TorchRL's ``TensorboardLogger``, event files under
    ``<run dir>/<exp_name>`` (needs ``tensorboard``).

    Examples:
        >>> TensorboardLoggerConf()._target_
        'torchrl.record.loggers.tensorboard.TensorboardLogger'
    """

    _target_: str = "torchrl.record.loggers.tensorboard.TensorboardLogger"

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_installed("tensorboard", "tensorboard")


@dataclass
class WandbLoggerConf(LoggerConf):
    """``logger=wandb``: TorchRL's ``WandbLogger``, offline by default (runs land in
    ``<run dir>/wandb``; ``wandb sync`` uploads them later).

    Examples:
        >>> WandbLoggerConf.offline  # an instance needs wandb installed
        True
    """

    _target_: str = "torchrl.record.loggers.wandb.WandbLogger"
    project: str = "sde_torchrl"
    offline: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_installed("wandb", "wandb")


#: Names of the files a job writes into its run directory (``sde_torchrl.jobs.run_dir``): a
#: logger's folder must not take one of them.
RUN_DIRECTORY_NAMES = (".hydra", ".lock", "job_config.json", "metrics.csv", "summary.json", "checkpoint.pt",
                       "checkpoint.prev.pt", "error.txt", "train.log", "final_policy.json")


def _check_exp_name(name: str) -> None:
    """A logger's folder name: it is created inside the run directory, and stays there, beside
    the job's own files (:data:`RUN_DIRECTORY_NAMES`, and their temporary ``.tmp`` names)."""
    if not name or "/" in name or "\\" in name or name in (".", ".."):
        raise ArgumentError("logger.exp_name", name, "a plain folder name (no '/', not '.' or '..'): the logger "
                                                     "writes into <run directory>/<exp_name>")
    if name.removesuffix(".tmp") in RUN_DIRECTORY_NAMES:
        raise ArgumentError("logger.exp_name", name, "a folder name other than the run directory's own files "
                                                     f"({', '.join(RUN_DIRECTORY_NAMES)})")


def _check_installed(module: str, package: str) -> None:
    """The logger's package can be imported (found, not imported: it may be slow to import)."""
    if importlib.util.find_spec(module) is None:
        raise ArgumentError("logger", module, f"a logger whose package is installed: {module} is not (pip install "
                                              f"{package}; or logger=csv or logger=none)")


@dataclass
class TrainConf:
    """The top-level config (``conf/config.yaml``); the groups are typed by their own schemas.

    Attributes:
        env: the ``env`` group's schema.
        actor: the ``actor`` group's schema.
        explorer: the ``explorer`` group's schema.
        estimator: the ``estimator`` group's schema.
        optimizer: the ``optimizer`` group's schema (``sgd``: eq. 1).
        logger: the ``logger`` group's schema; empty or ``null`` for none.
        algorithm: ``null``, the paper's episodic estimators (the ``estimator`` group), or the
            ``algorithm`` group's schema (``ppo``: :class:`PPOConf`, ``a2c``: :class:`A2CConf`,
            ``sac``: :class:`SACConf`), which trains one learner on
            ``env=gym`` with ``actor=mlp`` and ``estimator`` null; of the top-level keys it reads
            ``seed``, ``updates``, ``lr``, ``eval_period``, ``eval_episodes``, ``checkpoint_period``,
            ``progress`` and ``threads``.
        seed: job seed; run ``r``'s streams derive from ``(seed, first_run + r)``.
        runs: independent learners trained side by side in this process.
        first_run: global index of the first run (shards of a sweep).
        updates: policy updates.
        episodes_per_update: ``N``, fresh episodes per run and update.
        lr: ``α``, the base learning rate of the ``optimizer`` (with ``optimizer=sgd``, eq. 1's
            plain gradient ascent ``θ ← θ + α g``).
        eval_period: deterministic evaluation every this many updates (and after the last); 0:
            only after the last.
        eval_episodes: deterministic episodes per evaluation and run.
        r_lim: convergence threshold on the mean exploratory return (``null``: not tracked).
        stop_at_threshold: end the job once every run has exceeded ``r_lim``.
        tensor_rollout: collect by tensor stepping where the env allows (``false``: ``env.rollout``).
        episode_queue: ``Q > 0``: each update uses the last ``Q`` episodes per run (the
            ball-catching schedule); a multiple of ``episodes_per_update``.
        checkpoint_period: write ``checkpoint.pt`` every this many updates (0: only at the end).
        progress: progress bar; ``null``: only on a terminal and outside a multirun.
        threads: torch intra-op threads per job (a job is a sequence of small ops; the jobs of a
            sweep share the cores).
        max_memory_gb: refuse a job whose estimated memory (:mod:`sde_torchrl.jobs.resources`) exceeds
            this; ``null``: the memory the machine has available when the job starts.
        device: where the job's tensors live, ``cpu`` (the default), ``cuda`` or ``cuda:N``
            (:mod:`sde_torchrl.utils.devices`; refused before anything is built where that
            device is absent).

    Examples:
        >>> TrainConf(runs=4, r_lim=-1.8).episodes_per_update
        10
        >>> TrainConf().device
        'cpu'
    """

    env: Any = None
    actor: Any = None
    explorer: Any = None
    estimator: Any = None
    optimizer: Any = None
    logger: Any = None
    algorithm: Any = None
    seed: int = 0
    runs: int = 1
    first_run: int = 0
    updates: int = 200
    episodes_per_update: int = 10
    lr: float = 0.01
    eval_period: int = 20
    eval_episodes: int = 5
    r_lim: Optional[float] = None
    stop_at_threshold: bool = False
    tensor_rollout: bool = True
    episode_queue: int = 0
    checkpoint_period: int = 25
    progress: Optional[bool] = None
    threads: int = 1
    max_memory_gb: Optional[float] = None
    device: str = "cpu"

    def __post_init__(self) -> None:
        check_device_name(self.device)
        for name in ("runs", "threads"):
            positive_int(name, getattr(self, name))
        for name in ("seed", "checkpoint_period"):
            non_negative_int(name, getattr(self, name))
        if self.seed >= 2**64:  # torch seeds its generators with 64 bits
            raise ArgumentError("seed", self.seed, "an integer >= 0 and below 2**64")
        finite("lr", self.lr, minimum=0, strict=True)
        loop_settings(self)  # the training loop's own fields: TrainingSettings checks them
        if self.max_memory_gb is not None:
            finite("max_memory_gb", self.max_memory_gb, minimum=0, strict=True)
        if self.algorithm is not None:
            _check_onpolicy(self)
            return
        if isinstance(self.explorer, GaussianExplorerConf):
            raise ArgumentError("explorer", "gaussian", "an SDE or PGPE explorer for the episodic estimators "
                                                        "(explorer=gaussian is the baseline of algorithm=ppo and a2c)")
        if self.estimator is None and self.env is not None:
            raise ArgumentError("estimator", None, "an estimator (reinforce, enac, gpomdp, pgpe) unless "
                                                   "algorithm=ppo or a2c")
        _check_can_learn(self)
        _check_pgpe(self)
        if self.env is not None and self.estimator is not None:
            check_memory(self)


def loop_settings(conf: TrainConf) -> TrainingSettings:
    """The training loop's settings from the config's top level (each field of
    :class:`~sde_torchrl.trainers.settings.TrainingSettings` by its name) and the env's
    ``episode_length``; their rules are checked there, once.

    Examples:
        >>> loop_settings(TrainConf(updates=3)).updates
        3
    """
    values = {**vars(conf), "episode_length": getattr(conf.env, "episode_length", 1)}
    return TrainingSettings(**{f.name: values[f.name] for f in fields(TrainingSettings)})


def _check_onpolicy(conf: TrainConf) -> None:
    """What ``algorithm=ppo`` (``a2c``, ``sac``) trains on: one learner, a gymnasium env, an MLP
    actor, an SDE or Gaussian explorer, no episodic estimator; the SB3-style noise counts over its
    rollouts (SAC's: its rounds of ``train_freq`` steps)."""
    name = {A2CConf: "a2c", SACConf: "sac"}.get(type(conf.algorithm), "ppo")
    if conf.runs != 1:
        raise ArgumentError("runs", conf.runs, f"1 with algorithm={name} (one learner per job; sweep over seed "
                                               "for more)")
    if conf.device != "cpu":
        raise ArgumentError("device", conf.device, f"cpu with algorithm={name}")
    if conf.estimator is not None:
        target = str(getattr(conf.estimator, "_target_", "")).rsplit(".", 1)[-1]
        raise ArgumentError("estimator", target, f"null with algorithm={name} (its loss is the algorithm's): "
                                                 "estimator=null")
    if not isinstance(conf.env, GymEnvConf):
        target = str(getattr(conf.env, "_target_", "")).rsplit(".", 1)[-1]
        raise ArgumentError("env", target, f"env=gym with algorithm={name} (a gymnasium env such as "
                                           "env.id=Pendulum-v1)")
    if conf.env.normalize_obs is not None or conf.env.constant_feature:
        key = "env.normalize_obs" if conf.env.normalize_obs is not None else "env.constant_feature"
        raise ArgumentError(key, getattr(conf.env, key.split(".")[1]),
                            f"null (false) with algorithm={name}: it normalises with running statistics "
                            "(algorithm.normalize) and SDE sees the actor's last hidden layer")
    if not isinstance(conf.actor, MLPActorConf) or not conf.actor.bias:
        key, value = ("actor", str(getattr(conf.actor, "_target_", "")).rsplit(".", 1)[-1]) \
            if not isinstance(conf.actor, MLPActorConf) else ("actor.bias", False)
        raise ArgumentError(key, value, f"actor=mlp with bias with algorithm={name} (SDE's features are its "
                                        "last hidden layer)")
    if isinstance(conf.explorer, PGPEExplorerConf):
        raise ArgumentError("explorer", "pgpe", f"an SDE explorer (sde, gsde, ...) or gaussian with algorithm={name}")
    rollout, steps = ("train_freq", conf.algorithm.train_freq) if name == "sac" else ("n_steps", conf.algorithm.n_steps)
    if isinstance(conf.explorer, ExplorerConf):
        if conf.explorer.schedule in ROLLOUT_SCHEDULES and conf.explorer.rollout_steps not in (None, steps):
            raise ArgumentError("explorer.rollout_steps", conf.explorer.rollout_steps,
                                f"null or algorithm.{rollout} ({steps}) with algorithm={name}: "
                                "SB3 counts the noise's steps over each rollout")
    if name == "sac":
        _check_sac_explorer(conf.explorer)
    check_memory(conf)


def _check_sac_explorer(explorer: Any) -> None:
    """SAC's actor is tanh-squashed; its Gaussian learns a state-dependent log-std (SB3's SAC)."""
    if not explorer.squash:
        raise ArgumentError("explorer.squash", False, "true with algorithm=sac (SAC's actor is tanh-squashed)")
    if isinstance(explorer, GaussianExplorerConf) and not explorer.learn_sigma:
        raise ArgumentError("explorer.learn_sigma", False, "true with algorithm=sac and explorer=gaussian (its "
                                                           "log-std is a learned head of the actor)")


def _check_pgpe(conf: TrainConf) -> None:
    """``explorer=pgpe`` and ``estimator=pgpe`` only together; symmetric sampling on an even
    ``episodes_per_update`` (pairs ``μ ± ε``); at least two draws (the batch-mean baseline of a
    single draw cancels its return: every gradient would be exactly 0)."""
    pgpe_explorer = isinstance(conf.explorer, PGPEExplorerConf)
    pgpe_estimator = (getattr(conf.estimator, "_target_", "") or "").endswith("PGPEEstimator")
    if pgpe_explorer != pgpe_estimator:
        key = "estimator" if pgpe_explorer else "explorer"
        value = (getattr(getattr(conf, key), "_target_", "") or "").rsplit(".", 1)[-1]
        raise ArgumentError(key, value, "explorer=pgpe and estimator=pgpe go together (PGPE scores the parameter "
                                        "draws, which only explorer=pgpe makes)")
    if not pgpe_explorer:
        return
    if conf.explorer.symmetric and conf.episodes_per_update % 2:
        raise ArgumentError("episodes_per_update", conf.episodes_per_update,
                            "an even number with explorer=pgpe and explorer.symmetric=true (pairs μ ± ε), "
                            "or explorer.symmetric=false")
    draws = max(conf.episodes_per_update, conf.episode_queue) // (2 if conf.explorer.symmetric else 1)
    if draws < 2:
        raise ArgumentError("episodes_per_update", conf.episodes_per_update,
                            "at least 2 parameter draws per update with estimator=pgpe (4 episodes with "
                            "symmetric sampling): the batch-mean baseline of one draw cancels its return")


def _check_can_learn(conf: TrainConf) -> None:
    """Refuses settings under which no update can change the policy (hours of compute for nothing).

    REINFORCE's optimal baseline over a single episode equals that episode's return (GPOMDP's,
    each step's reward): with one episode per update and no queue, every gradient is exactly 0.
    ENAC with fewer episodes than parameters + 1 is not refused: its regression is rank-deficient, but the minimum-norm
    solution it then takes is not zero, only noisy: a warning once the parameters are counted
    (:func:`sde_torchrl.config.build.warn_if_rank_deficient`).
    """
    target = getattr(conf.estimator, "_target_", "") or ""
    name = next((n for suffix, n in BASELINE_ESTIMATORS.items() if target.endswith(suffix)), None)
    if name is not None and max(conf.episodes_per_update, conf.episode_queue) < 2:
        raise ArgumentError(
            "episodes_per_update", conf.episodes_per_update,
            f"at least 2 with estimator={name} (or an episode_queue of 2 or more): over a single "
            "episode the optimal baseline equals its return (GPOMDP's: each reward), so every gradient is exactly 0")


#: Estimators whose optimal baseline cancels a single episode: ``_target_`` suffix → group option.
BASELINE_ESTIMATORS = {"ReinforceEstimator": "reinforce", "GPOMDPEstimator": "gpomdp"}


#: ``schema/<name>`` → dataclass; YAML files name these first in their defaults list.
SCHEMAS: dict[str, type] = {
    "config": TrainConf,
    "env/minimize": MinimizeEnvConf,
    "env/gym": GymEnvConf,
    "env/ballcatch": BallCatchEnvConf,
    "actor/linear": LinearActorConf,
    "actor/mlp": MLPActorConf,
    "explorer/sde": ExplorerConf,
    "explorer/pgpe": PGPEExplorerConf,
    "explorer/gaussian": GaussianExplorerConf,
    "algorithm/ppo": PPOConf,
    "algorithm/a2c": A2CConf,
    "algorithm/sac": SACConf,
    "estimator/episodic": EstimatorConf,
    "optimizer/sgd": SGDOptimizerConf,
    "optimizer/adam": AdamOptimizerConf,
    "optimizer/rmsprop": RMSpropOptimizerConf,
    "logger/csv": CSVLoggerConf,
    "logger/tensorboard": TensorboardLoggerConf,
    "logger/wandb": WandbLoggerConf,
}


def register_configs() -> None:
    """Stores every schema in Hydra's ``ConfigStore`` (idempotent)."""
    store = ConfigStore.instance()
    for path, node in SCHEMAS.items():
        group, _, name = f"schema/{path}".rpartition("/")
        store.store(group=group, name=name, node=node)


def register_resolvers() -> None:
    """Config resolvers and the config schemas (:func:`register_configs`): call before composing
    a config. The resolvers: ``${midway_r_lim:T,x0,s,noise_std,theta0}`` (``midway_threshold``);
    ``${sde_memory_gb:}``, ``${sde_memory_bytes:}`` and ``${sde_time_min:}``, a launcher's request
    for the job (:func:`~sde_torchrl.jobs.resources.launcher_request`). Light: torch is imported when a
    value is resolved, not here (``train.py`` locks its run directory before importing torch)."""
    register_configs()

    def midway_r_lim(T, x0, s, noise, theta0):  # noqa: N803 - the paper's symbols
        from sde_torchrl.envs.minimize import midway_threshold

        return midway_threshold(int(T), float(x0), float(s), float(noise), float(theta0))

    OmegaConf.register_new_resolver("midway_r_lim", midway_r_lim, replace=True)
    # The launchers' requests per job (conf/hydra/launcher/*.yaml), from the job's sizes.
    OmegaConf.register_new_resolver("sde_memory_gb", lambda _root_: launcher_request(_root_)["mem_gb"],
                                    replace=True)
    OmegaConf.register_new_resolver("sde_time_min", lambda _root_: launcher_request(_root_)["timeout_min"],
                                    replace=True)
    OmegaConf.register_new_resolver("sde_memory_bytes", lambda _root_: int(launcher_request(_root_)["mem_gb"] * 1e9),
                                    replace=True)


def validate(cfg: DictConfig) -> TrainConf:
    """The composed config as schema objects, every value checked (once, before anything is built).

    Args:
        cfg: the composed config.

    Returns:
        The :class:`TrainConf`, its groups as their schemas' dataclasses, interpolations resolved.

    Raises:
        ArgumentError: for the first value that is not allowed.
    """
    return OmegaConf.to_object(cfg)


# ------------------------------------------------------------------------ error reporting


def describe_error(error: BaseException) -> str | None:
    """One line ``<key>=<value>: <what is allowed>`` for a config error, else ``None``.

    Understands :class:`~sde_torchrl.utils.checks.ArgumentError` (the schemas' checks), Hydra's unknown
    group options and override errors and OmegaConf's validation errors (wrong type, unknown
    key), also when wrapped by Hydra.
    """
    from hydra.errors import ConfigCompositionException, MissingConfigException, OverrideParseException
    from omegaconf.errors import OmegaConfBaseException

    for err in _chain(error):
        if isinstance(err, ArgumentError):
            return str(err)
        if isinstance(err, MissingConfigException):
            return _missing_option(err)
        if isinstance(err, OmegaConfBaseException) and getattr(err, "full_key", None):
            return _omegaconf_line(err)
    for err in _chain(error):
        if isinstance(err, (ConfigCompositionException, OverrideParseException, OmegaConfBaseException)):
            return " ".join(str(err).split())
    return None


def _chain(error: BaseException) -> list[BaseException]:
    chain, seen = [], set()
    while error is not None and id(error) not in seen:
        chain.append(error)
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return chain


def _missing_option(err: Any) -> str:
    path = err.missing_cfg_file or ""
    group, _, option = path.rpartition("/")
    options = [o for o in (err.options or []) if not o.startswith("schema")]
    if group and options:
        return f"{group}={option}: expected one of {', '.join(sorted(options))}"
    return " ".join(str(err).split())


_TYPE_WORDS = {"Integer": "an integer", "Float": "a number", "Boolean": "true or false",
               "String": "a string"}


def _omegaconf_line(err: Any) -> str:
    key = err.full_key
    value = getattr(err, "value", None)  # not always set by OmegaConf
    msg = str(getattr(err, "msg", "") or err).splitlines()[0]
    if "not in struct" in msg or "Key '" in msg and "not in" in msg:
        return f"{key}: unknown key"
    expected = getattr(err, "ref_type", None) or getattr(err, "object_type_str", None)
    if value is None and "Value '" in msg:
        value = msg.split("Value '", 1)[1].split("'", 1)[0]
    allowed = msg
    if "could not be converted to" in msg:
        type_name = msg.rsplit("could not be converted to", 1)[1].strip().rstrip(".")
        allowed = _TYPE_WORDS.get(type_name, f"a value of type {type_name}")
    elif expected:
        allowed = f"{msg} (expected {expected})"
    return f"{key}={show(value)}: {allowed}" if value is not None else f"{key}: {allowed}"

