"""The ``algorithm`` group's schemas: PPO and A2C (on-policy actor-critic, their shared options
in :class:`OnPolicyConf`) and SAC, which train one learner in place of the episodic estimators.

Examples:
    >>> PPOConf().n_steps, A2CConf().n_steps, SACConf().train_freq
    (2048, 5, 1)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, List, Optional

from sde_torchrl.config.schemas.frozen import Frozen
from sde_torchrl.utils.checks import (
    ArgumentError,
    finite,
    fraction,
    is_finite_number,
    is_int,
    non_negative_int,
    one_of,
    positive_int,
)

# ``typing`` generics, not ``list[int]`` or ``X | None``: OmegaConf reads these annotations at runtime.
# ruff: noqa: UP006, UP007, UP035, UP045


@dataclass
class OnPolicyConf(Frozen):
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
        compile: compile the loss's forward and backward with ``torch.compile`` and step Adam or
            SGD with torch's fused kernel (:mod:`sde_torchrl.trainers.objective`): faster updates,
            a first update tens of seconds longer, results equal to the eager ones to rounding.

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
    compile: bool = False

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
class PPOConf(OnPolicyConf, schema="algorithm/ppo"):
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
class A2CConf(OnPolicyConf, schema="algorithm/a2c"):
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
class SACConf(Frozen, schema="algorithm/sac"):
    """``algorithm=sac``: Soft Actor-Critic with TorchRL's ``SACLoss`` and ``ReplayBuffer`` on one
    gymnasium env (:mod:`sde_torchrl.trainers.offpolicy`, :mod:`sde_torchrl.trainers.sac`); the
    defaults are Stable-Baselines3's ``SAC`` defaults. ``lr`` and ``optimizer`` (Adam) are the top
    level's; ``updates`` counts rows of ``metrics.csv``, each ``rounds_per_update × train_freq``
    env steps. The actor is tanh-squashed (``explorer.squash`` must be true).

    Attributes:
        buffer_size: transitions the replay buffer keeps.
        batch_size: transitions per minibatch, at most ``buffer_size``.
        learning_starts: env steps of uniform random actions before the first gradient step, a
            multiple of ``train_freq`` and below the job's env steps (checked with ``updates``:
            :func:`~sde_torchrl.config.schemas.train.validate`).
        train_freq: env steps collected per round.
        gradient_steps: gradient steps after each round.
        gamma: discount.
        tau: the target critics' Polyak coefficient.
        ent_coef: the entropy coefficient: ``auto`` (learned, from 1, target entropy ``-dim(A)``)
            or a fixed number > 0.
        rounds_per_update: rounds per update (a row of ``metrics.csv``, a checkpoint boundary).
        time_feature: append ``1 - t / episode_length`` to the observation (sb3-contrib's
            ``TimeFeatureWrapper``).
        compile: compile the critic's and the actor's losses with ``torch.compile`` and step
            Adam with torch's fused kernel (:mod:`sde_torchrl.trainers.sac`): faster gradient
            steps, a first one tens of seconds longer, results equal to the eager ones to rounding.

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
    compile: bool = False

    def __post_init__(self) -> None:
        for name in ("buffer_size", "batch_size", "train_freq", "gradient_steps", "rounds_per_update"):
            positive_int(f"algorithm.{name}", getattr(self, name))
        if self.batch_size > self.buffer_size:
            raise ArgumentError("algorithm.batch_size", self.batch_size,
                                f"at most algorithm.buffer_size = {self.buffer_size} (a minibatch is drawn from the "
                                "transitions the replay buffer keeps)")
        non_negative_int("algorithm.learning_starts", self.learning_starts)
        if self.learning_starts % self.train_freq:
            raise ArgumentError("algorithm.learning_starts", self.learning_starts,
                                f"a multiple of algorithm.train_freq ({self.train_freq}): the warm-up ends with a "
                                "round of collection")
        fraction("algorithm.gamma", self.gamma)
        fraction("algorithm.tau", self.tau)
        if self.ent_coef != "auto" and not (is_finite_number(self.ent_coef) and self.ent_coef > 0):
            raise ArgumentError("algorithm.ent_coef", self.ent_coef, "auto or a finite number > 0")

