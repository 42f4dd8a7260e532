"""Schemas that a validated config freezes: :func:`~sde_torchrl.config.schemas.train.validate`
builds the job's config once, and from then on nothing assigns to it.

The schemas cannot be ``@dataclass(frozen=True)``: OmegaConf makes a frozen dataclass's node
read-only, and Hydra merges YAML files and overrides into the nodes. So each schema is frozen as
an instance once validated (:func:`freeze`): assigning to a field then raises
:class:`dataclasses.FrozenInstanceError`. A schema also registers itself where it is defined:
``class MyConf(Frozen, schema="env/my")`` puts it into :data:`SCHEMAS`, which
:func:`~sde_torchrl.config.registration.register_configs` stores in Hydra's ``ConfigStore`` as
``schema/env/my``.

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

#: ``<group>/<option>`` (``config`` for the top level) → the schema that declared that name.
SCHEMAS: dict[str, type] = {}


class Frozen:
    """A schema whose instance :func:`freeze` makes read-only.

    Args:
        schema: in the class statement, the name the schema registers under (:data:`SCHEMAS`);
            none for a base that no group option uses as it is.
    """

    def __init_subclass__(cls, schema: str | None = None, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if schema is not None:
            SCHEMAS[schema] = cls

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
