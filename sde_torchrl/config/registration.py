"""The schemas in Hydra's ``ConfigStore`` and the config's resolvers: what must be registered
before a config is composed (:func:`register_resolvers`).

Every group option's YAML file names its schema first in its defaults list
(``/schema/<group>/<option>@_here_``) and holds only what differs from it; ``conf/config.yaml``
names ``/schema/config``.

Examples:
    >>> SCHEMAS["estimator/enac"].option
    'enac'
"""

from __future__ import annotations

from hydra.core.config_store import ConfigStore
from omegaconf import OmegaConf

from sde_torchrl.config.schemas.algorithms import A2CConf, PPOConf, SACConf
from sde_torchrl.config.schemas.envs import BallCatchEnvConf, GymEnvConf, MinimizeEnvConf
from sde_torchrl.config.schemas.estimators import (
    ENACEstimatorConf,
    GPOMDPEstimatorConf,
    PGPEEstimatorConf,
    ReinforceEstimatorConf,
)
from sde_torchrl.config.schemas.loggers import CSVLoggerConf, TensorboardLoggerConf, WandbLoggerConf
from sde_torchrl.config.schemas.optimizers import AdamOptimizerConf, RMSpropOptimizerConf, SGDOptimizerConf
from sde_torchrl.config.schemas.policy import (
    ExplorerConf,
    GaussianExplorerConf,
    LinearActorConf,
    MLPActorConf,
    PGPEExplorerConf,
)
from sde_torchrl.config.schemas.train import TrainConf
from sde_torchrl.jobs.resources import launcher_request

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
    "estimator/reinforce": ReinforceEstimatorConf,
    "estimator/enac": ENACEstimatorConf,
    "estimator/gpomdp": GPOMDPEstimatorConf,
    "estimator/pgpe": PGPEEstimatorConf,
    "optimizer/sgd": SGDOptimizerConf,
    "optimizer/adam": AdamOptimizerConf,
    "optimizer/rmsprop": RMSpropOptimizerConf,
    "logger/csv": CSVLoggerConf,
    "logger/tensorboard": TensorboardLoggerConf,
    "logger/wandb": WandbLoggerConf,
}


def register_configs() -> None:
    """Stores every schema in Hydra's ``ConfigStore`` (idempotent).

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
    OmegaConf.register_new_resolver("sde_memory_gb", lambda _root_: launcher_request(_root_)["mem_gb"],
                                    replace=True)
    OmegaConf.register_new_resolver("sde_time_min", lambda _root_: launcher_request(_root_)["timeout_min"],
                                    replace=True)
    OmegaConf.register_new_resolver("sde_memory_bytes", lambda _root_: int(launcher_request(_root_)["mem_gb"] * 1e9),
                                    replace=True)
