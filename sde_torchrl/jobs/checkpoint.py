"""Checkpoints that resume a job bit for bit, written atomically.

A job's state between two updates is: the policy and optimiser state dicts, the number of
updates done, every random generator it draws from (the explorer's and the envs' per-run
:class:`~sde_torchrl.utils.rng.RunStreams`; the global generators, as TorchRL's
:class:`~torchrl.checkpoint.GlobalRNGState` captures them) and the bookkeeping the summary is
computed from. Restoring all of it and continuing produces exactly the numbers an uninterrupted
job produces (on CPU). :func:`save_job` and :func:`restore_job` write and read that state: the
file is replaced atomically, and its content carries a checksum (:func:`content_digest`) verified
on load, so a damaged file raises :class:`~sde_torchrl.utils.files.DamagedFileError` rather than
resuming from wrong numbers; ``torch.load(..., weights_only=True)`` still reads it.

The file is not a :class:`torchrl.checkpoint.Checkpoint`: that one's save leaves no checkpoint if
killed between its two renames, its manifest has no checksums, its load changes each component
as it reads it (a resume must check the whole file first and change nothing if a check fails),
and it writes a directory or zip of per-tensor files, not one file.
"""

from __future__ import annotations

import hashlib
import logging
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from torchrl.checkpoint import GlobalRNGState

from sde_torchrl.jobs.metrics import RECORDS
from sde_torchrl.utils.files import DamagedFileError, write_atomically
from sde_torchrl.utils.rng import RunStreams

log = logging.getLogger(__name__)

CHECKPOINT = "checkpoint.pt"
#: The checkpoint before the last one, kept by :func:`save_job`: a damaged ``checkpoint.pt``
#: then costs the updates since it, not the whole job.
PREVIOUS = "checkpoint.prev.pt"
#: Bumped when the checkpoint layout changes; older checkpoints are refused, but for :data:`READABLE`.
FORMAT = 4
#: Formats this version resumes: 3 differs from 4 only in naming torch's generator ``torch``
#: (ours) where :class:`~torchrl.checkpoint.GlobalRNGState` names it ``torch_cpu``.
READABLE = (3, 4)
#: Config keys that do not change the numbers a job produces: they may differ on resume.
NON_RESULT_KEYS = ("logger", "checkpoint_period", "progress", "max_memory_gb")
#: Config keys added after checkpoints were written, with their defaults: at its default such a
#: key is left out of the result config, so that those checkpoints still resume. Off its default
#: it counts (``device=cuda`` rounds otherwise than the CPU: not the same job). A dotted key names
#: an option inside a config group.
LATER_KEYS = {"device": "cpu", "env.observation": "raw", "algorithm": None, "optimizer.sigma_lr_factor": 1.0,
              "scores": "autograd", "queue_scores": "rescored", "final_episodes": 0}


class CheckpointMismatchError(ValueError):
    """The run directory holds a checkpoint of a different job."""


def save_checkpoint(path: str | os.PathLike, state: dict[str, Any]) -> None:
    """``torch.save`` of ``state`` with its :func:`content_digest` under ``sha256``, atomically
    (:func:`~sde_torchrl.utils.files.write_atomically`)."""
    state = {**state, "sha256": content_digest(state)}
    write_atomically(path, lambda f: torch.save(state, f))


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Loads a checkpoint written by :func:`save_checkpoint` (tensors and plain data only) and
    verifies its checksum.

    Raises:
        DamagedFileError: the file cannot be read, or its content does not match its checksum.
        CheckpointMismatchError: it was written by a version with another checkpoint format.

    Examples:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "checkpoint.pt"
        >>> save_checkpoint(path, {"format": FORMAT, "updates": 3})
        >>> load_checkpoint(path)
        {'format': 4, 'updates': 3}
    """
    path = Path(path)
    remedy = (f"nothing was resumed from it; to train the job again from the start, delete {path.name} "
              f"(copy {path.parent / 'metrics.csv'} elsewhere first to keep the updates done so far)")
    if path.stat().st_size == 0:
        raise DamagedFileError(path, "it is empty", remedy)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)  # restore_job puts each piece where it lives
    except FileNotFoundError:
        raise
    except Exception as error:  # noqa: BLE001 - whatever the damage, the file cannot be used
        reason = " ".join(str(error).split()).split(". ")[0][:200] or "no detail"  # torch's first sentence
        raise DamagedFileError(path, f"it cannot be read ({type(error).__name__}: {reason})", remedy) from error
    if not isinstance(state, dict):
        raise DamagedFileError(path, f"it holds a {type(state).__name__}, not a checkpoint", remedy)
    digest = state.pop("sha256", None)
    if digest is None and state.get("format") not in READABLE:
        raise CheckpointMismatchError(
            f"{path} has checkpoint format {state.get('format')!r}, this version reads {FORMAT}; "
            "finish the job with the version that wrote it, or delete it to start over"
        )
    if digest != content_digest(state):
        problem = "its checksum is missing" if digest is None else "its content does not match its checksum"
        raise DamagedFileError(path, problem, remedy)
    if state.get("format") not in READABLE:
        raise CheckpointMismatchError(f"{path} has checkpoint format {state.get('format')!r}, this version "
                                      f"reads {FORMAT}; delete it to start over")
    return state


def content_digest(state: Any) -> str:
    """SHA-256 of a checkpoint's content: every tensor's dtype, shape and bytes, every plain
    value, in order, so that equal digests mean equal content.

    Examples:
        >>> content_digest({"a": torch.zeros(2)}) == content_digest({"a": torch.zeros(2)})
        True
        >>> content_digest({"a": torch.zeros(2)}) == content_digest({"a": torch.zeros(3)})
        False
    """
    digest = hashlib.sha256()
    _feed(digest, state)
    return digest.hexdigest()


def _feed(digest: Any, value: Any) -> None:
    if isinstance(value, torch.Tensor):
        tensor = value.detach().cpu().contiguous().reshape(-1)
        digest.update(f"T{tensor.dtype}{tuple(value.shape)}".encode())
        digest.update(tensor.view(torch.uint8).numpy().tobytes())
    elif isinstance(value, dict):
        digest.update(f"D{len(value)}".encode())
        for key, item in value.items():
            _feed(digest, key)
            _feed(digest, item)
    elif isinstance(value, (list, tuple)):
        digest.update(f"{type(value).__name__}{len(value)}".encode())
        for item in value:
            _feed(digest, item)
    else:
        text = f"{type(value).__name__}:{value!r}"
        digest.update(f"S{len(text)}:{text}".encode())


def result_config(config: dict[str, Any] | None) -> dict[str, Any] | None:
    """The part of a resolved config that determines a job's results (:data:`LATER_KEYS` at
    their defaults left out).

    Examples:
        >>> result_config({"seed": 1, "progress": True, "device": "cpu"})
        {'seed': 1}
        >>> result_config({"seed": 1, "device": "cuda", "env": {"model": "cup", "observation": "raw"}})
        {'seed': 1, 'device': 'cuda', 'env': {'model': 'cup'}}
    """
    if config is None:
        return None
    return _without_defaults({k: v for k, v in config.items() if k not in NON_RESULT_KEYS}, "")


def _without_defaults(config: dict[str, Any], prefix: str) -> dict[str, Any]:
    """``config`` without the :data:`LATER_KEYS` (under ``prefix``) that hold their defaults."""
    out = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if name in LATER_KEYS and value == LATER_KEYS[name]:
            continue
        nested = isinstance(value, dict) and any(later.startswith(f"{name}.") for later in LATER_KEYS)
        out[key] = _without_defaults(value, f"{name}.") if nested else value
    return out


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
    """States of Python's, NumPy's, torch's and any initialised accelerator's global generators
    (:class:`~torchrl.checkpoint.GlobalRNGState`: tensors and plain data, so that
    ``torch.load(..., weights_only=True)`` reads them).

    Examples:
        >>> sorted(global_random_state())
        ['numpy', 'python', 'torch_cpu']
    """
    return GlobalRNGState().state_dict()


def set_global_random_state(state: dict[str, Any]) -> None:
    """Restores what :func:`global_random_state` returned (or a format-3 checkpoint's ``random``).

    Raises:
        CheckpointMismatchError: it holds an accelerator's generators and this machine has none.

    Examples:
        >>> state = global_random_state()
        >>> first = torch.rand(2)
        >>> set_global_random_state(state)
        >>> bool((torch.rand(2) == first).all())
        True
    """
    if "torch" in state:  # format 3
        state = {**{k: v for k, v in state.items() if k != "torch"}, "torch_cpu": state["torch"]}
    try:
        GlobalRNGState().load_state_dict(state)
    except RuntimeError as error:  # "Checkpoint contains CUDA RNG state but CUDA is unavailable."
        raise CheckpointMismatchError(f"the checkpoint cannot be resumed here: {error}") from error


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


def job_streams(policy: torch.nn.Module, env: Any, eval_env: Any) -> dict[str, RunStreams | None]:
    """The per-run random streams of a job: the explorer's and both envs'."""
    explorer = module_streams(policy)
    return {"explorer": explorer[0] if explorer else None,
            "env": env_streams(env), "eval_env": env_streams(eval_env)}


def save_job(
    path: Path, *, config: dict[str, Any] | None, loop: dict[str, Any], policy: torch.nn.Module,
    optimizer: torch.optim.Optimizer, streams: dict[str, RunStreams | None],
) -> None:
    """Saves everything :func:`restore_job` needs to continue a job bit for bit.

    Args:
        path: the checkpoint file.
        config: the job's result config (see :func:`result_config`), what the run directory
            checks a resumed job against.
        loop: the training loop's bookkeeping (its ``state_dict``), with ``update`` in it.
        policy: the policy whose state dict is saved.
        optimizer: the optimiser whose state dict is saved.
        streams: the job's per-run streams (:func:`job_streams`).

    The checkpoint it replaces is kept as :data:`PREVIOUS` beside it (a copy).
    """
    if path.exists():
        keep_previous(path, path.with_name(PREVIOUS))
    save_checkpoint(path, {
        "format": FORMAT,
        "config": config,
        "updates": loop["update"],
        "policy": policy.state_dict(),
        "optimizer": optimizer.state_dict(),
        "streams": {k: None if v is None else v.state_dict() for k, v in streams.items()},
        "random": global_random_state(),
        "loop": loop,
    })


def keep_previous(path: Path, previous: Path) -> None:
    """Makes ``previous`` a durable copy of ``path``, replacing it atomically: at every moment
    one of the two is a complete checkpoint. A copy, not a hard link: a job killed between this
    and the next checkpoint's rename would otherwise leave both names on one file, and damaging
    one would damage both. (TorchRL's :class:`~torchrl.checkpoint.CheckpointRotation` rotates
    only its own checkpoints, and picks the newest by manifest even when that one is damaged.)

    Examples:
        >>> import tempfile
        >>> folder = Path(tempfile.mkdtemp())
        >>> _ = (folder / CHECKPOINT).write_bytes(b"state")
        >>> keep_previous(folder / CHECKPOINT, folder / PREVIOUS)
        >>> (folder / PREVIOUS).read_bytes(), (folder / PREVIOUS).stat().st_nlink
        (b'state', 1)
    """
    data = path.read_bytes()
    write_atomically(previous, lambda f: f.write(data))


def _pointing_to_previous(error: DamagedFileError, previous: Path) -> DamagedFileError:
    """``error``, its remedy pointing to ``previous`` if that checkpoint is intact."""
    try:
        updates = load_checkpoint(previous)["updates"]
    except (OSError, DamagedFileError, CheckpointMismatchError, KeyError):
        return error
    return DamagedFileError(error.path, error.problem, (
        f"nothing was resumed from it; {previous.name} (after update {updates}) is intact: replace "
        f"{error.path.name} with it (mv {previous} {error.path}) to resume from there"))


def check_content(saved: dict[str, Any], policy: torch.nn.Module, updates: int | None) -> str | None:
    """What makes a checkpoint's content unusable for this job, or ``None``: the update counter
    outside ``[0, updates]`` or not the loop's, a policy entry missing, extra, or of another shape
    or dtype than this job's, per-update records of another shape. A checksum only says the file
    is what was written; this says that what was written fits the job.

    Examples:
        >>> policy = torch.nn.Linear(2, 1)
        >>> loop = {"update": 3, "returns": torch.zeros(3, 1)}
        >>> check_content({"updates": 3, "policy": policy.state_dict(), "loop": loop}, policy, 10) is None
        True
        >>> check_content({"updates": -3, "policy": policy.state_dict(), "loop": loop}, policy, 10)
        'its update counter is -3, outside [0, 10]'
    """
    done = saved.get("updates")
    if not isinstance(done, int) or isinstance(done, bool) or done < 0 or (updates is not None and done > updates):
        return f"its update counter is {done!r}, outside [0, {updates}]"
    loop = saved.get("loop")
    if not isinstance(loop, dict) or loop.get("update") != done:
        return f"its loop record is at update {loop.get('update') if isinstance(loop, dict) else None!r}, not {done}"
    own, theirs = policy.state_dict(), saved.get("policy")
    if not isinstance(theirs, dict) or set(theirs) != set(own):
        names = sorted(set(own) ^ set(theirs or {}))
        return f"its policy entries differ from this job's ({', '.join(names[:4])})"
    for name, tensor in own.items():
        stored = theirs[name]
        if not isinstance(stored, torch.Tensor) or stored.shape != tensor.shape or stored.dtype != tensor.dtype:
            what = (f"{tuple(stored.shape)} {stored.dtype}" if isinstance(stored, torch.Tensor)
                    else type(stored).__name__)
            return f"its policy entry {name!r} is {what}, this job's is {tuple(tensor.shape)} {tensor.dtype}"
    for key in (r.key for r in RECORDS):
        record = loop.get(key)
        if isinstance(record, torch.Tensor) and record.shape[:1] != (done,):
            return f"its {key} record has {record.shape[0] if record.dim() else 0} updates, not {done}"
    return None


def read_checkpoint(path: Path) -> dict[str, Any]:
    """:func:`load_checkpoint` of a job's ``checkpoint.pt``, a damaged one's remedy pointing to
    :data:`PREVIOUS` when that one is intact.

    Raises:
        DamagedFileError: the file is damaged.
        CheckpointMismatchError: it has another checkpoint format.

    Examples:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / CHECKPOINT
        >>> save_checkpoint(path, {"format": FORMAT, "updates": 3})
        >>> read_checkpoint(path)["updates"]
        3
    """
    try:
        return load_checkpoint(path)
    except DamagedFileError as error:
        raise _pointing_to_previous(error, path.with_name(PREVIOUS)) from error


def restore_job(
    path: Path, *, policy: torch.nn.Module, optimizer: torch.optim.Optimizer,
    streams: dict[str, RunStreams | None], updates: int | None = None,
) -> dict[str, Any]:
    """Restores a job saved by :func:`save_job` and returns the loop's bookkeeping.

    Policy, optimiser, the per-run streams and the global generators are restored in place. The
    checkpoint checks itself only (its checksum, format and fit to the job): whether it is this
    job's, of this config, the run directory decides before
    (:meth:`~sde_torchrl.jobs.run_dir.RunDirectory.check_job`).

    Args:
        updates: the job's number of updates (the checkpoint's counter must not exceed it).

    Raises:
        CheckpointMismatchError: the checkpoint has another format, or holds streams this job
            does not have.
        DamagedFileError: the file is damaged, or its content does not fit the job
            (:func:`check_content`).
    """
    saved = read_checkpoint(path)
    problem = check_content(saved, policy, updates)
    if problem is not None:
        error = DamagedFileError(path, problem, f"nothing was resumed from it; delete {path.name} to train the job "
                                                "again from the start")
        raise _pointing_to_previous(error, path.with_name(PREVIOUS))
    policy.load_state_dict(saved["policy"])
    optimizer.load_state_dict(saved["optimizer"])
    for name, own in streams.items():
        if saved["streams"].get(name) is not None:
            if own is None:
                raise CheckpointMismatchError(f"{path} holds {name} streams this job does not have")
            own.load_state_dict(saved["streams"][name])
        elif own is not None:
            log.warning("checkpoint has no %s streams: the resumed job is not bitwise reproducible", name)
    set_global_random_state(saved["random"])
    return saved["loop"]
