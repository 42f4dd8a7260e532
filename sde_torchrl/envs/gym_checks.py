"""What ``env=gym`` needs of a gymnasium env, checked with gymnasium alone (no torch).

The config schema (:class:`~sde_torchrl.config.schemas.envs.GymEnvConf`) runs :func:`check_gym_env` on a
registered id before anything is built, and :class:`~sde_torchrl.envs.gym.GymRunsEnv` runs
:func:`check_spaces` and :func:`check_time_limit` on the env it builds (``"module:Env-v0"`` ids,
Python callers). Both raise :class:`~sde_torchrl.utils.checks.ArgumentError` naming the config key, so
that ``train.py`` reports either as one line with the config-error exit code.

While the envs run, :func:`check_env_output` refuses an observation or a reward that holds NaN or
infinity after a finite action (:class:`EnvOutputError`): the env produced it, and no training
setting would change it, so the job stops naming the env and the step rather than leaving it to
the non-finite guard, which would take it for a diverged policy.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from sde_torchrl.utils.checks import ArgumentError


class EnvOutputError(RuntimeError):
    """A gymnasium env returned a non-finite observation or reward after finite actions.

    Args:
        env_id: the gymnasium id.
        what: ``"observation"`` or ``"reward"``.
        value: what the env returned (its first 6 entries are shown).
        where: when, in words (``"step 3 of env 0's episode (seed 12), after a finite action"``).

    Examples:
        >>> str(EnvOutputError("my_envs:Bad-v0", "reward", float("nan"), "step 3"))  # doctest: +ELLIPSIS
        'env my_envs:Bad-v0 returned a non-finite reward [nan] at step 3: the env made it, and no training ...'
    """

    def __init__(self, env_id: str, what: str, value: Any, where: str) -> None:
        import numpy as np

        self.env_id, self.what, self.where = env_id, what, where
        shown = [float(f"{v:.6g}") for v in np.asarray(value, dtype=np.float64).reshape(-1)[:6]]
        super().__init__(f"env {env_id} returned a non-finite {what} {shown} at {where}: the env made it, and no "
                         "training setting changes that; check the env, or choose another env.id")


def check_env_output(env_id: str, where: str, observation: Any, reward: Any = None, action: Any = None) -> None:
    """Refuses a non-finite observation or reward that an env returned after a finite ``action``.

    After a non-finite action (a diverged policy's) nothing is checked: the trainer's non-finite
    guard names the update and the parameters.

    Args:
        env_id: the gymnasium id, for the message.
        where: the step, in words (:class:`EnvOutputError`).
        observation: the observation returned (array-like).
        reward: the reward returned (``None`` after a reset).
        action: the action the env was stepped with (``None`` after a reset).

    Raises:
        EnvOutputError: the observation or the reward holds NaN or infinity.

    Examples:
        >>> check_env_output("Pendulum-v1", "step 1", [0.0, 1.0], 0.5, action=[0.1])
        >>> check_env_output("Pendulum-v1", "step 1", [float("nan")], 0.5, action=[float("nan")])  # the policy's
    """
    import numpy as np

    if action is not None and not np.isfinite(np.asarray(action, dtype=np.float64)).all():
        return
    for what, value in (("observation", observation), ("reward", reward)):
        if value is not None and not np.isfinite(np.asarray(value, dtype=np.float64)).all():
            raise EnvOutputError(env_id, what, value, where if action is None else f"{where}, after a finite action")


def check_spaces(env_id: str, action_space: Any, observation_space: Any) -> None:
    """Refuses spaces SDE cannot act in or compute features from.

    Args:
        env_id: the gymnasium id, for the message.
        action_space: the env's action space; must be a 1-D ``Box``.
        observation_space: the env's observation space; must be a 1-D ``Box``.

    Raises:
        ArgumentError: on ``env.id``, naming the space the env has.

    Examples:
        >>> from gymnasium.spaces import Box, Discrete
        >>> check_spaces("Pendulum-v1", Box(-2, 2, (1,)), Box(-8, 8, (3,)))
        >>> try:
        ...     check_spaces("CartPole-v1", Discrete(2), Box(-1, 1, (4,)))
        ... except ArgumentError as error:
        ...     print(error.allowed)
        an env with a continuous (Box) action space; CartPole-v1 has Discrete(2)
    """
    from gymnasium.spaces import Box

    if not isinstance(action_space, Box):
        allowed, space = "an env with a continuous (Box) action space", action_space
    elif len(action_space.shape) != 1:
        allowed, space = "an env with a flat (1-D Box) action space", action_space
    elif not isinstance(observation_space, Box) or len(observation_space.shape) != 1:
        allowed, space = "an env with a flat (1-D Box) observation space", observation_space
    else:
        return
    raise ArgumentError("env.id", env_id, f"{allowed}; {env_id} has {' '.join(repr(space).split())}")


def check_time_limit(env_id: str, episode_length: int, time_limit: int | None) -> None:
    """Refuses an episode longer than the env's time limit, advising the override that raises it.

    Args:
        env_id: the gymnasium id, for the message.
        episode_length: ``T``, the steps per episode asked for.
        time_limit: the env's ``max_episode_steps`` (``None``: no limit).

    Raises:
        ArgumentError: on ``env.episode_length``, with the override to type.

    Examples:
        >>> check_time_limit("Pendulum-v1", 200, 200)
        >>> try:
        ...     check_time_limit("Pendulum-v1", 300, 200)
        ... except ArgumentError as error:
        ...     print(error.allowed)
        at most 200 (Pendulum-v1's time limit; raise it with env.gym_kwargs.max_episode_steps=300)
    """
    if time_limit is not None and episode_length > time_limit:
        raise ArgumentError("env.episode_length", episode_length,
                            f"at most {time_limit} ({env_id}'s time limit; raise it with "
                            f"env.gym_kwargs.max_episode_steps={episode_length})")


def check_gym_env(env_id: str, episode_length: int, gym_kwargs: Mapping[str, Any]) -> None:
    """Makes the env once with ``gym_kwargs`` (closed right away) and checks its spaces and time limit.

    A few milliseconds for the classic-control envs: a bad env is refused while the config is
    checked, not seconds later when the training envs are built.

    Args:
        env_id: a registered gymnasium id.
        episode_length: ``T``, the steps per episode asked for.
        gym_kwargs: keyword arguments for ``gymnasium.make``.

    Raises:
        ArgumentError: for keyword arguments the env does not take, unsupported spaces, or an
            episode longer than the time limit.

    Examples:
        >>> check_gym_env("Pendulum-v1", 300, {"max_episode_steps": 300})
    """
    import gymnasium

    try:
        env = gymnasium.make(env_id, **gym_kwargs)
    except TypeError as error:  # gymnasium re-raises the env's own TypeError with its kwargs appended
        given = {k: v for k, v in gym_kwargs.items() if not (k == "max_episode_steps" and v is None)}
        reason = " ".join(str(error.__cause__ or error).split())
        raise ArgumentError("env.gym_kwargs", given, f"keyword arguments {env_id} takes ({reason})") from error
    try:
        check_spaces(env_id, env.action_space, env.observation_space)
        check_time_limit(env_id, episode_length, env.spec.max_episode_steps)
    finally:
        env.close()
