"""The ``env`` group's schemas: the function-minimisation task, ball catching, any gymnasium env.

Each declares, beside its options, what the layers that never make the env need of it
(:class:`EnvConf`): its sizes and memory for the estimate before a job is built
(:mod:`sde_torchrl.jobs.resources`), and its report on a finished job
(:mod:`sde_torchrl.envs.outcomes`).

Examples:
    >>> MinimizeEnvConf().episode_length, BallCatchEnvConf().episode_length
    (15, 500)
    >>> MinimizeEnvConf(dim=2).sizes(), BallCatchEnvConf().sizes(), GymEnvConf().sizes()
    ((2, 2), (3, 4), None)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Optional

from sde_torchrl.config.schemas.frozen import Frozen
from sde_torchrl.envs.outcomes import OutcomeReport, declare_report
from sde_torchrl.utils.checks import ArgumentError, finite, is_finite_number, is_int, one_of, positive_int
from sde_torchrl.utils.options import NORMALIZATIONS, REWARD_STATES

# ``typing`` generics, not ``X | None``: OmegaConf reads these annotations at runtime.
# ruff: noqa: UP007, UP045

#: ``env.model``'s names. The arms are kept beside the models' data, which imports pybullet on use:
#: a test checks the two agree.
ARM_MODELS = ("pybrain", "cup", "pybrain_held", "pybrain_strong_fingers")

#: One pybullet world: ball catching's (the PyBrain arm's 15 hinges, the ball, their contacts; a
#: PyBullet gymnasium env's is counted the same).
WORLD_BYTES = 28e6
#: One gymnasium env (TorchRL's ``GymEnv`` around it): Pendulum-v1, 15-19 kB measured.
GYM_ENV_BYTES = 20e3


@dataclass
class EnvConf(Frozen):
    """What every env schema declares for the layers that never make the env. An env's schema
    subclasses it and registers under its option (``class MyEnvConf(EnvConf, schema="env/my")``);
    it must define :meth:`sizes` (a schema that does not is refused when defined) and has a
    field ``episode_length``.

    Attributes:
        steps_per_second: env steps per second and core that the time estimate assumes (a class
            attribute; 20,000 unless declared).
        size_settings: the env's own size keys with their smallest values, which a job too large
            for memory may be told to lower (a class attribute; ``{"dim": 1}`` for ``minimize``).
    """

    steps_per_second: ClassVar[int] = 20_000
    size_settings: ClassVar[dict[str, Any]] = {}

    def __init_subclass__(cls, schema: str | None = None, **kwargs: Any) -> None:
        if schema is not None and cls.sizes is EnvConf.sizes:
            raise TypeError(f"{cls.__name__} (schema {schema}) declares no sizes: an env schema defines "
                            "sizes(), its (observation, action) sizes, or None where only the made env tells them")
        super().__init_subclass__(schema=schema, **kwargs)
        if schema is not None and cls.outcomes is not EnvConf.outcomes:
            declare_report(schema.rsplit("/", 1)[-1], cls.outcomes)

    def sizes(self) -> tuple[int, int] | None:
        """The observation and action sizes as the config tells them, before the env is made;
        ``None``: only the made env tells them (the estimate then assumes a size of its own)."""
        raise NotImplementedError

    def slot_bytes(self) -> float:
        """Memory one env of the batch holds besides the steps' tensors, in bytes (a simulator
        world); 0 unless declared."""
        return 0.0

    @staticmethod
    def outcomes() -> OutcomeReport | None:
        """The env's report on a finished job (:mod:`sde_torchrl.envs.outcomes`); ``None``: its
        returns alone."""
        return None


@dataclass
class MinimizeEnvConf(EnvConf, schema="env/minimize"):
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

    size_settings: ClassVar[dict[str, Any]] = {"dim": 1}

    def sizes(self) -> tuple[int, int]:
        return self.dim, self.dim

    def __post_init__(self) -> None:
        positive_int("env.episode_length", self.episode_length)
        positive_int("env.dim", self.dim)
        finite("env.x0_spread", self.x0_spread, minimum=0)
        finite("env.noise_std", self.noise_std, minimum=0)
        finite("env.step_size", self.step_size)
        one_of("env.reward_state", self.reward_state, REWARD_STATES)


@dataclass
class BallCatchEnvConf(EnvConf, schema="env/ballcatch"):
    """``env=ballcatch``: an arm with a hand catches a ball released above the palm (pybullet,
    paper section 4.2).

    Attributes:
        episode_length: steps of 0.01 s per episode.
        jitter: half-width of the uniform horizontal release offset, in ``[0, 0.4]``.
        model: the arm, ``pybrain`` (after PyBrain's ``arm.xode``, the authors' arm), ``cup``, or a
            diagnostic: ``pybrain_held`` (the pybrain arm with shoulder, elbow and wrist held) or
            ``pybrain_strong_fingers`` (the pybrain arm with its finger actuator doubled).
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

    steps_per_second: ClassVar[int] = 2000  # 2,400 measured for 2 jobs on 2 cores with tests beside them

    def sizes(self) -> tuple[int, int]:
        return 3, 4  # the ball's position; shoulder, elbow, wrist and finger torques

    def slot_bytes(self) -> float:
        return WORLD_BYTES

    @staticmethod
    def outcomes() -> OutcomeReport:
        """The paper's catching levels and what the policies did with the ball
        (:class:`~sde_torchrl.envs.ballcatch.report.CatchReport`)."""
        from sde_torchrl.envs.ballcatch.report import CatchReport

        return CatchReport()

    def __post_init__(self) -> None:
        positive_int("env.episode_length", self.episode_length)
        one_of("env.observation", self.observation, ("raw", "scaled"))
        if not is_finite_number(self.jitter) or not 0 <= self.jitter <= 0.4:
            raise ArgumentError("env.jitter", self.jitter, "a number in [0, 0.4]")
        one_of("env.model", self.model, ARM_MODELS)


@dataclass
class GymEnvConf(EnvConf, schema="env/gym"):
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

    def sizes(self) -> None:
        return None  # the spaces are read off the env once made

    def slot_bytes(self) -> float:
        return WORLD_BYTES if "Bullet" in self.id else GYM_ENV_BYTES

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

