"""Argument checks shared by the config schemas and the constructors: one wording everywhere.

Every failed check raises :class:`ArgumentError`, whose message is one line
``<name>=<value>: <what is allowed>``, the same whether the value came from a Hydra override
(``env.episode_length=-3: a positive integer``) or from Python (``episodes=0: a positive
integer``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any


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


def one_of(name: str, value: Any, allowed: Iterable[str]) -> str:
    """Returns ``value`` if it is one of ``allowed``; raises :class:`ArgumentError` otherwise."""
    allowed = tuple(allowed)
    if value not in allowed:
        raise ArgumentError(name, value, f"one of {', '.join(allowed)}")
    return value
