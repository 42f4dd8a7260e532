"""Config errors in one line, ``<key>=<value>: <what is allowed>``, whichever part refused the
config: the schemas' checks (:class:`~sde_torchrl.utils.checks.ArgumentError`), Hydra (an unknown
group option, a bad override) or OmegaConf (a wrong type, an unknown key).

Examples:
    >>> from sde_torchrl.utils.checks import ArgumentError
    >>> describe_error(ArgumentError("runs", 0, "a positive integer"))
    'runs=0: a positive integer'
"""

from __future__ import annotations

from typing import Any

from hydra.errors import ConfigCompositionException, MissingConfigException, OverrideParseException
from omegaconf.errors import OmegaConfBaseException

from sde_torchrl.config.schemas.train import unknown_key
from sde_torchrl.utils.checks import ArgumentError, show


def describe_error(error: BaseException) -> str | None:
    """One line ``<key>=<value>: <what is allowed>`` for a config error, else ``None``.

    Understands :class:`~sde_torchrl.utils.checks.ArgumentError` (the schemas' checks), Hydra's unknown
    group options and override errors and OmegaConf's validation errors (wrong type, unknown
    key), also when wrapped by Hydra.

    Examples:
        >>> from sde_torchrl.config.compose import compose
        >>> try:
        ...     compose(["estimator=gpomdp", "estimator.symmetric=true"])
        ... except ConfigCompositionException as error:
        ...     describe_error(error)  # doctest: +ELLIPSIS
        "estimator.symmetric: unknown key (estimator=gpomdp's options: max_grad_norm, ...)"
    """
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
        return f"{key}: {unknown_key(key.rpartition('.')[0], getattr(err, 'object_type', None))}"
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

