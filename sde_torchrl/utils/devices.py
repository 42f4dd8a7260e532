"""The ``device`` a job trains on: the name checked without torch, then against this machine.

A job's tensors (the envs' states and outputs, the policy's parameters, the noise, the
episodes and the estimators' work) live on one device, ``device=cpu`` by default. The name is
checked twice: its form by the config schema (:func:`check_device_name`, no torch: ``train.py``
checks its config before torch is imported), and whether this machine has that device by
:func:`training_device` before anything is built (:func:`~sde_torchrl.config.build.build_trainer`),
so that ``device=cuda`` where there is no CUDA fails in one line with exit code 2, not after
the envs are up. What stays on the CPU whatever the device: the per-run random streams'
generators (:class:`~sde_torchrl.utils.rng.RunStreams`: the draws are made there and moved, so a
seed gives the same numbers on every device), pybullet's physics, gymnasium's envs, ENAC's
least squares (an SVD driver only the CPU has) and the trainer's bookkeeping
(``metrics.csv``, ``summary.json``, the checkpoint's records).
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any

from sde_torchrl.utils.checks import ArgumentError

if TYPE_CHECKING:
    import torch

#: What ``device=`` accepts for training, in words.
TRAINING_DEVICES = "cpu, cuda or cuda:N"
_NAME = re.compile(r"(cpu|cuda(:\d+)?)")


def check_device_name(value: Any, name: str = "device") -> str:
    """The form of a training device's name: ``cpu``, ``cuda`` or ``cuda:N`` (no torch needed).

    ``meta`` is refused: it carries shapes without data, for tests only (nothing can be
    trained on it).

    Args:
        value: the name given.
        name: the config key, for the message.

    Returns:
        ``value``.

    Raises:
        ArgumentError: for any other value.

    Examples:
        >>> check_device_name("cuda:1")
        'cuda:1'
        >>> check_device_name("meta")
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.checks.ArgumentError: device=meta: cpu, cuda or cuda:N (meta holds no data: it is for tests)
    """
    if not isinstance(value, str) or not _NAME.fullmatch(value):
        extra = " (meta holds no data: it is for tests)" if value == "meta" else ""
        raise ArgumentError(name, value, TRAINING_DEVICES + extra)
    return value


def training_device(value: Any, name: str = "device") -> torch.device:
    """The ``torch.device`` to train on, refused unless this machine has it.

    Args:
        value: ``cpu``, ``cuda`` or ``cuda:N``.
        name: the config key, for the message.

    Returns:
        The device.

    Raises:
        ArgumentError: for a name of another form (:func:`check_device_name`), for ``cuda``
            where torch sees no CUDA device, or for ``cuda:N`` beyond the devices present; the
            message names the fix.

    Examples:
        >>> training_device("cpu")
        device(type='cpu')
    """
    import torch

    check_device_name(value, name)
    device = torch.device(value)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ArgumentError(name, value, "this machine has no CUDA device (torch.cuda.is_available() is False); "
                                             "run with device=cpu")
        count = torch.cuda.device_count()
        if device.index is not None and device.index >= count:
            raise ArgumentError(name, value, f"this machine has {count} CUDA device(s): use cuda:0 to "
                                             f"cuda:{count - 1}, or device=cpu")
    return device


__all__ = ["TRAINING_DEVICES", "check_device_name", "training_device"]
