"""The schemas in Hydra's ``ConfigStore`` and the config's resolvers: what must be registered
before a config is composed (:func:`register_resolvers`).

Every schema registers itself where it is defined (``class MyConf(Frozen, schema="env/my")``,
:data:`~sde_torchrl.config.schemas.frozen.SCHEMAS`); this module imports every module of
:mod:`sde_torchrl.config.schemas`, so that a schema in any of them is found. Every group option's
YAML file names its schema first in its defaults list (``/schema/<group>/<option>@_here_``) and
holds only what differs from it; ``conf/config.yaml`` names ``/schema/config``.

Examples:
    >>> SCHEMAS["estimator/enac"].option
    'enac'
"""

from __future__ import annotations

import importlib
import pkgutil
from types import SimpleNamespace

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf

from sde_torchrl.config import schemas
from sde_torchrl.config.schemas.frozen import SCHEMAS
from sde_torchrl.jobs.resources import launcher_request

for _module in pkgutil.iter_modules(schemas.__path__):
    importlib.import_module(f"{schemas.__name__}.{_module.name}")


def register_configs() -> None:
    """Stores every schema in Hydra's ``ConfigStore`` as ``schema/<name>`` (idempotent); a
    schema defined after this module was imported (a user's own) is stored by the next call.

    Examples:
        >>> register_configs()
        >>> ConfigStore.instance().load("schema/estimator/pgpe.yaml").node._target_
        'sde_torchrl.objectives.pgpe.PGPEEstimator'
    """
    store = ConfigStore.instance()
    for path, node in SCHEMAS.items():
        group, _, name = f"schema/{path}".rpartition("/")
        store.store(group=group, name=name, node=node)


def register_resolvers() -> None:
    """Config resolvers and the config schemas (:func:`register_configs`): call before composing
    a config. The resolvers: ``${midway_r_lim:T,x0,s,noise_std,theta0}`` (``midway_threshold``);
    ``${sde_memory_gb:}``, ``${sde_memory_bytes:}`` and ``${sde_time_min:}``, a launcher's request
    for the job (:func:`~sde_torchrl.jobs.resources.launcher_request`). Light: torch is imported when a
    value is resolved, not here (``train.py`` locks its run directory before importing torch).

    Examples:
        >>> register_resolvers()
        >>> OmegaConf.has_resolver("midway_r_lim"), OmegaConf.has_resolver("sde_memory_gb")
        (True, True)
    """
    register_configs()

    def midway_r_lim(T, x0, s, noise, theta0):  # noqa: N803 - the paper's symbols
        from sde_torchrl.envs.minimize import midway_threshold

        return midway_threshold(int(T), float(x0), float(s), float(noise), float(theta0))

    OmegaConf.register_new_resolver("midway_r_lim", midway_r_lim, replace=True)
    # The launchers' requests per job (conf/hydra/launcher/*.yaml), from the job's sizes.
    OmegaConf.register_new_resolver("sde_memory_gb", lambda _root_: launcher_request(job_of(_root_))["mem_gb"],
                                    replace=True)
    OmegaConf.register_new_resolver("sde_time_min", lambda _root_: launcher_request(job_of(_root_))["timeout_min"],
                                    replace=True)
    OmegaConf.register_new_resolver(
        "sde_memory_bytes", lambda _root_: int(launcher_request(job_of(_root_))["mem_gb"] * 1e9), replace=True)


def job_of(root: DictConfig) -> SimpleNamespace:
    """A composed config as the resource estimates read it: Hydra's own node left out, each
    group as its schema's object (what the schemas declare is on those objects, not on the nodes)."""
    return SimpleNamespace(**{key: OmegaConf.to_object(node) if isinstance(node, DictConfig) else node
                              for key, node in root.items() if key != "hydra"})
