"""Argument checks shared by the config schemas and the constructors: one wording everywhere.

Every failed check raises :class:`ArgumentError`, whose message is one line
``<name>=<value>: <what is allowed>``, the same whether the value came from a Hydra override
(``env.episode_length=-3: a positive integer``) or from Python (``episodes=0: a positive
integer``). Batched tensor inputs (actions, episodes) that hold NaN or infinity raise
:class:`NonFiniteInputError`, naming the input, the batch entries concerned and the fix
(:func:`~sde_torchrl.utils.nonfinite.check_finite`, under the non-finite policy).

This module does not import torch (``train.py`` checks its config before torch is imported):
the tensor checks only call the tensors' own methods.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

from sde_torchrl.utils.options import PERIODIC_SCHEDULES, ROLLOUT_SCHEDULES, SCHEDULES


class ArgumentError(ValueError):
    """A value that is not allowed.

    Args:
        name: the argument or dotted config key (``explorer.sharing``).
        value: the value given.
        allowed: what would be accepted, in words.

    Examples:
        >>> str(ArgumentError("runs", -1, "a positive integer"))
        'runs=-1: a positive integer'
    """

    def __init__(self, name: str, value: Any, allowed: str) -> None:
        self.key, self.value, self.allowed = name, value, allowed
        super().__init__(f"{name}={show(value)}: {allowed}")


class NonFiniteInputError(ValueError):
    """A batched tensor input that holds NaN or infinity.

    Args:
        name: the input (``action``, ``episodes key 'observation'``).
        where: the batch entries concerned, in words (:func:`batch_entries`).
        fix: what to do about it.

    Examples:
        >>> str(NonFiniteInputError("action", "run 1 episode 0", "check the policy"))
        'action: NaN/inf in run 1 episode 0; check the policy'
    """

    def __init__(self, name: str, where: str, fix: str) -> None:
        self.key, self.where, self.fix = name, where, fix
        super().__init__(f"{name}: NaN/inf in {where}; {fix}")


def batch_entries(mask: Any, labels: Sequence[str], limit: int = 4) -> str:
    """The batch entries where a boolean tensor is true, in words (the first ``limit``).

    Args:
        mask: boolean tensor with one dimension per label.
        labels: the name of each dimension (``("run", "episode")``).
        limit: entries shown; the others are counted.

    Examples:
        >>> import torch
        >>> batch_entries(torch.tensor([[False, True], [True, True]]), ("run", "episode"), limit=2)
        'run 0 episode 1, run 1 episode 0 (and 1 more)'
    """
    hits = mask.nonzero().tolist()
    shown = ", ".join(" ".join(f"{label} {i}" for label, i in zip(labels, index, strict=True))
                      for index in hits[:limit])
    return shown + (f" (and {len(hits) - limit} more)" if len(hits) > limit else "")


def show(value: Any) -> str:
    """A value as a user would type it in an override (``null``, ``true``, ``[1, 2]``)."""
    if hasattr(value, "_is_missing"):  # an OmegaConf node: show its plain content
        from omegaconf import OmegaConf

        value = OmegaConf.to_container(value)
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)


def is_int(value: Any) -> bool:
    """An integer, and not a bool."""
    return isinstance(value, int) and not isinstance(value, bool)


def is_finite_number(value: Any) -> bool:
    """A finite int or float, and not a bool."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


#: The largest finite float32: a value stored in a float32 parameter must not exceed it.
FLOAT32_MAX = 3.4028234663852886e38


def float32_number(name: str, value: Any) -> float:
    """Returns ``value`` if it is a finite number a float32 parameter can hold (``|value| <= 3.4e38``).

    Raises:
        ArgumentError: otherwise.

    Examples:
        >>> float32_number("explorer.init_param", -2.0)
        -2.0
        >>> float32_number("explorer.init_param", -1e308)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.checks.ArgumentError: explorer.init_param=-1e+308: a finite number within float32's range ...
    """
    if not is_finite_number(value) or abs(value) > FLOAT32_MAX:
        raise ArgumentError(name, value, f"a finite number within float32's range (|x| <= {FLOAT32_MAX:.2g})")
    return value


def positive_int(name: str, value: Any) -> int:
    """Returns ``value`` if it is an integer >= 1.

    Raises:
        ArgumentError: otherwise.

    Examples:
        >>> positive_int("runs", 3)
        3
    """
    if not is_int(value) or value < 1:
        raise ArgumentError(name, value, "a positive integer")
    return value


def non_negative_int(name: str, value: Any) -> int:
    """Returns ``value`` if it is an integer >= 0; raises :class:`ArgumentError` otherwise."""
    if not is_int(value) or value < 0:
        raise ArgumentError(name, value, "an integer >= 0")
    return value


def finite(name: str, value: Any, *, minimum: float | None = None, strict: bool = False) -> float:
    """Returns ``value`` if it is a finite number (``>= minimum``, or ``> minimum`` if ``strict``).

    Raises:
        ArgumentError: otherwise.

    Examples:
        >>> finite("lr", 0.1, minimum=0, strict=True)
        0.1
    """
    ok = is_finite_number(value) and (minimum is None or value > minimum or (not strict and value == minimum))
    if not ok:
        bound = "" if minimum is None else f" {'>' if strict else '>='} {minimum:g}"
        raise ArgumentError(name, value, f"a finite number{bound}")
    return value


def fraction(name: str, value: Any, *, below_one: bool = False) -> float:
    """Returns ``value`` if it is a number in ``[0, 1]`` (``[0, 1)`` if ``below_one``).

    Raises:
        ArgumentError: otherwise.

    Examples:
        >>> fraction("optimizer.momentum", 0.9, below_one=True)
        0.9
    """
    if not is_finite_number(value) or not (0 <= value < 1 if below_one else 0 <= value <= 1):
        raise ArgumentError(name, value, "a number in [0, 1)" if below_one else "a number in [0, 1]")
    return value


def one_of(name: str, value: Any, allowed: Iterable[str]) -> str:
    """Returns ``value`` if it is one of ``allowed``; raises :class:`ArgumentError` otherwise."""
    allowed = tuple(allowed)
    if value not in allowed:
        raise ArgumentError(name, value, f"one of {', '.join(allowed)}")
    return value


def multiple_of(name: str, value: int, base_name: str, base: int) -> int:
    """Returns ``value`` if it is 0 or a multiple of ``base``; raises :class:`ArgumentError` otherwise.

    Examples:
        >>> multiple_of("episode_queue", 7, "episodes_per_update", 2)
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.checks.ArgumentError: episode_queue=7: 0 or a multiple of episodes_per_update (2)
    """
    if value % base:
        raise ArgumentError(name, value, f"0 or a multiple of {base_name} ({base})")
    return value


def noise_schedule(
    schedule: Any, every_n: Any, prefix: str = "", rollout_steps: Any = None
) -> tuple[str, int | None]:
    """Checks an SDE noise schedule: one of :data:`~sde_torchrl.utils.options.SCHEDULES`;
    ``every_n`` a positive integer with ``"every_n"`` or ``"every_n_steps"``, ``None`` otherwise;
    ``rollout_steps`` ``None`` or a positive integer, and ``None`` unless ``"every_n_steps"`` or
    ``"rollout"``.

    Args:
        schedule: the schedule.
        every_n: the redraw period.
        prefix: the options' prefix in messages (``"explorer."`` for the config).
        rollout_steps: the rollout length over which SB3-style schedules count.

    Returns:
        ``(schedule, every_n)``.

    Raises:
        ArgumentError: naming the option.

    Examples:
        >>> noise_schedule("every_n", 5)
        ('every_n', 5)
        >>> noise_schedule("episode", 3)
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.checks.ArgumentError: every_n=3: null unless schedule=every_n or every_n_steps
        >>> noise_schedule("step", None, rollout_steps=8)
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.checks.ArgumentError: rollout_steps=8: null unless schedule=every_n_steps or rollout
    """
    one_of(f"{prefix}schedule", schedule, SCHEDULES)
    if schedule in PERIODIC_SCHEDULES:
        positive_int(f"{prefix}every_n", every_n)
    elif every_n is not None:
        raise ArgumentError(f"{prefix}every_n", every_n,
                            f"null unless {prefix}schedule={' or '.join(PERIODIC_SCHEDULES)}")
    if schedule in ROLLOUT_SCHEDULES:
        if rollout_steps is not None:
            positive_int(f"{prefix}rollout_steps", rollout_steps)
    elif rollout_steps is not None:
        raise ArgumentError(f"{prefix}rollout_steps", rollout_steps,
                            f"null unless {prefix}schedule={' or '.join(ROLLOUT_SCHEDULES)}")
    return schedule, every_n
