"""Schemas that a validated config freezes: :func:`~sde_torchrl.config.schemas.train.validate`
builds the job's config once, and from then on nothing assigns to it.

The schemas cannot be ``@dataclass(frozen=True)``: Hydra composes the config by merging YAML
files and overrides into nodes typed by them, and OmegaConf makes a frozen dataclass's node
read-only. So each schema is frozen as an instance, once validated (:func:`freeze`): its fields
are set, and assigning to one raises :class:`dataclasses.FrozenInstanceError`, as for a frozen
dataclass.

Examples:
    >>> from dataclasses import dataclass
    >>> @dataclass
    ... class Conf(Frozen):
    ...     lr: float = 0.1
    >>> conf = freeze(Conf())
    >>> conf.lr = 0.2
    Traceback (most recent call last):
    ...
    dataclasses.FrozenInstanceError: cannot assign to field 'lr' of a validated config
"""

from __future__ import annotations

from dataclasses import FrozenInstanceError, fields, is_dataclass
from typing import Any, TypeVar

T = TypeVar("T")

#: The instance attribute that marks a frozen schema (outside its fields: not in ``asdict``).
_FROZEN = "_frozen_"


class Frozen:
    """A schema whose instance :func:`freeze` makes read-only."""

    def __setattr__(self, name: str, value: Any) -> None:
        if self.__dict__.get(_FROZEN, False):
            raise FrozenInstanceError(f"cannot assign to field {name!r} of a validated config")
        super().__setattr__(name, value)

    def __delattr__(self, name: str) -> None:
        if self.__dict__.get(_FROZEN, False):
            raise FrozenInstanceError(f"cannot delete field {name!r} of a validated config")
        super().__delattr__(name)


def freeze(conf: T) -> T:
    """Freezes ``conf`` and the schemas it holds (its groups), and returns it.

    Examples:
        >>> from sde_torchrl.config.schemas.train import TrainConf
        >>> from sde_torchrl.config.schemas.estimators import ENACEstimatorConf
        >>> conf = freeze(TrainConf(estimator=ENACEstimatorConf()))
        >>> conf.estimator.max_grad_norm = 1.0  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        dataclasses.FrozenInstanceError: cannot assign to field 'max_grad_norm' of a validated config
    """
    if isinstance(conf, Frozen):
        for field in fields(conf) if is_dataclass(conf) else ():
            freeze(getattr(conf, field.name))
        object.__setattr__(conf, _FROZEN, True)
    return conf
