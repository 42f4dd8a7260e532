"""Checkpoints that resume a job bit for bit, written atomically.

A job's state between two updates is: the policy and optimiser state dicts, the number of
updates done, every random generator it draws from (the explorer's and the envs' per-run
:class:`~sde_torchrl.rng.RunStreams`, torch's, NumPy's and Python's global generators) and the
bookkeeping the summary is computed from. Restoring all of it and continuing produces exactly
the numbers an uninterrupted job produces (on CPU).

Files are replaced atomically: written to ``<name>.tmp``, flushed to disk, then renamed over
the old one, so a reader (or a resumed job) sees the previous complete file or the new one.
"""

from __future__ import annotations

import os
import random
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sde_torchrl.rng import RunStreams

CHECKPOINT = "checkpoint.pt"
#: Bumped when the checkpoint layout changes; older checkpoints are refused.
FORMAT = 1
#: Config keys that do not change the numbers a job produces: they may differ on resume.
NON_RESULT_KEYS = ("logger", "checkpoint_period", "progress")


class CheckpointMismatchError(ValueError):
    """The run directory holds a checkpoint of a different job."""


def tmp_path(path: Path) -> Path:
    """The temporary name ``path`` is written under before being renamed."""
    return path.with_name(path.name + ".tmp")


def replace_atomically(tmp: Path, path: Path) -> None:
    """Renames the fully written ``tmp`` over ``path`` and makes the rename durable."""
    os.replace(tmp, path)
    try:
        fd = os.open(path.parent, os.O_RDONLY)
    except OSError:  # directories cannot be opened everywhere; the rename is still atomic
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def save_checkpoint(path: str | os.PathLike, state: dict[str, Any]) -> None:
    """``torch.save`` to a temporary file, fsync, rename over ``path``."""
    path = Path(path)
    tmp = tmp_path(path)
    with open(tmp, "wb") as f:
        torch.save(state, f)
        f.flush()
        os.fsync(f.fileno())
    replace_atomically(tmp, path)


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Loads a checkpoint written by :func:`save_checkpoint` (tensors and plain data only)."""
    state = torch.load(path, weights_only=True)
    if state.get("format") != FORMAT:
        raise CheckpointMismatchError(
            f"{path} has checkpoint format {state.get('format')!r}, this version reads {FORMAT}; "
            "delete it or use another run directory"
        )
    return state


def result_config(config: dict[str, Any] | None) -> dict[str, Any] | None:
    """The part of a resolved config that determines a job's results."""
    if config is None:
        return None
    return {k: v for k, v in config.items() if k not in NON_RESULT_KEYS}


def config_differences(saved: Any, current: Any, prefix: str = "") -> list[str]:
    """``key: saved -> current`` for every leaf that differs between two config dicts."""
    if isinstance(saved, dict) and isinstance(current, dict):
        out = []
        for key in sorted(set(saved) | set(current), key=str):
            name = f"{prefix}.{key}" if prefix else str(key)
            out += config_differences(saved.get(key, "<absent>"), current.get(key, "<absent>"), name)
        return out
    return [] if saved == current else [f"{prefix}: {saved!r} -> {current!r}"]


def global_random_state() -> dict[str, Any]:
    """States of torch's, NumPy's and Python's global generators (tensors and plain data, so
    that ``torch.load(..., weights_only=True)`` reads them)."""
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    numpy_state = [kind, torch.from_numpy(keys.astype(np.int64)), int(pos), int(has_gauss), float(cached)]
    return {"torch": torch.get_rng_state(), "numpy": numpy_state, "python": random.getstate()}


def set_global_random_state(state: dict[str, Any]) -> None:
    """Restores what :func:`global_random_state` returned."""
    torch.set_rng_state(state["torch"])
    kind, keys, pos, has_gauss, cached = state["numpy"]
    np.random.set_state((kind, keys.numpy().astype(np.uint32), pos, has_gauss, cached))
    random.setstate(state["python"])


def env_streams(env: Any) -> RunStreams | None:
    """The per-run streams of ``env`` or of the env it wraps (``_streams``), if any."""
    for layer in _env_layers(env):
        streams = getattr(layer, "_streams", None)
        if isinstance(streams, RunStreams):
            return streams
    return None


def _env_layers(env: Any) -> Iterator[Any]:
    seen = set()
    while env is not None and id(env) not in seen:
        seen.add(id(env))
        yield env
        env = getattr(env, "base_env", None)


def module_streams(module: torch.nn.Module) -> list[RunStreams]:
    """The per-run streams held by ``module``'s submodules (the explorer's), in module order."""
    return [m.streams for m in module.modules() if isinstance(getattr(m, "streams", None), RunStreams)]
