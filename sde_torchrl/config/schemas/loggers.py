"""The ``logger`` group's schemas: TorchRL's loggers, each writing into a folder of the run
directory (``logger=none``: no logger, ``metrics.csv`` only).

Examples:
    >>> CSVLoggerConf().exp_name, WandbLoggerConf.offline
    ('sde_torchrl', True)
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass

from sde_torchrl.config.schemas.frozen import Frozen
from sde_torchrl.utils.checks import ArgumentError


@dataclass
class LoggerConf(Frozen):
    """What every ``logger`` option has: TorchRL's logger class and the folder it writes into,
    ``<run dir>/<exp_name>``, which must stay inside the run directory.

    Examples:
        >>> try:
        ...     LoggerConf(exp_name="../x")
        ... except ArgumentError as error:
        ...     print(str(error).split(":")[0])
        logger.exp_name=../x
    """

    _target_: str = "torchrl.record.loggers.csv.CSVLogger"
    exp_name: str = "sde_torchrl"

    def __post_init__(self) -> None:
        _check_exp_name(self.exp_name)


@dataclass
class CSVLoggerConf(LoggerConf, schema="logger/csv"):
    """``logger=csv``: TorchRL's ``CSVLogger``, run-averaged curves under the run directory.

    Examples:
        >>> CSVLoggerConf().exp_name
        'sde_torchrl'
    """


@dataclass
class TensorboardLoggerConf(LoggerConf, schema="logger/tensorboard"):
    """``logger=tensorboard``: TorchRL's ``TensorboardLogger``, event files under
    ``<run dir>/<exp_name>`` (needs ``tensorboard``).

    Examples:
        >>> TensorboardLoggerConf()._target_
        'torchrl.record.loggers.tensorboard.TensorboardLogger'
    """

    _target_: str = "torchrl.record.loggers.tensorboard.TensorboardLogger"

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_installed("tensorboard", "tensorboard")


@dataclass
class WandbLoggerConf(LoggerConf, schema="logger/wandb"):
    """``logger=wandb``: TorchRL's ``WandbLogger``, offline by default (runs land in
    ``<run dir>/wandb``; ``wandb sync`` uploads them later).

    Examples:
        >>> WandbLoggerConf.offline  # an instance needs wandb installed
        True
    """

    _target_: str = "torchrl.record.loggers.wandb.WandbLogger"
    project: str = "sde_torchrl"
    offline: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_installed("wandb", "wandb")


#: Names of the files a job writes into its run directory (``sde_torchrl.jobs.run_dir``): a
#: logger's folder must not take one of them.
RUN_DIRECTORY_NAMES = (".hydra", ".lock", "job_config.json", "metrics.csv", "summary.json", "checkpoint.pt",
                       "checkpoint.prev.pt", "error.txt", "train.log", "final_policy.json")


def _check_exp_name(name: str) -> None:
    """A logger's folder name: it is created inside the run directory, and stays there, beside
    the job's own files (:data:`RUN_DIRECTORY_NAMES`, and their temporary ``.tmp`` names)."""
    if not name or "/" in name or "\\" in name or name in (".", ".."):
        raise ArgumentError("logger.exp_name", name, "a plain folder name (no '/', not '.' or '..'): the logger "
                                                     "writes into <run directory>/<exp_name>")
    if name.removesuffix(".tmp") in RUN_DIRECTORY_NAMES:
        raise ArgumentError("logger.exp_name", name, "a folder name other than the run directory's own files "
                                                     f"({', '.join(RUN_DIRECTORY_NAMES)})")


def _check_installed(module: str, package: str) -> None:
    """The logger's package can be imported (found, not imported: it may be slow to import)."""
    if importlib.util.find_spec(module) is None:
        raise ArgumentError("logger", module, f"a logger whose package is installed: {module} is not (pip install "
                                              f"{package}; or logger=csv or logger=none)")

