"""The command line's exit codes and one-line errors: each failure of a job or of Hydra's
composition as one line for stderr, with the exit code that says which kind it is.

Part of :mod:`sde_torchrl.cli`; standard library and light config modules only (no torch), since a
job reports a refused run directory before anything heavy is imported.
"""

from __future__ import annotations

import errno
import os
import sys
from pathlib import Path

from sde_torchrl.config.errors import describe_error
from sde_torchrl.jobs.lock import RunDirectoryInUse
from sde_torchrl.utils.files import DamagedFileError, FileWriteError

EXIT_FAILED, EXIT_CONFIG, EXIT_IN_USE, EXIT_DAMAGED, EXIT_INTERRUPTED = 1, 2, 3, 4, 130


def debug_mode() -> bool:
    """Full tracebacks wanted (``SDE_TORCHRL_DEBUG=1`` or ``HYDRA_FULL_ERROR=1``)?"""
    return any(os.environ.get(name, "") not in ("", "0") for name in ("SDE_TORCHRL_DEBUG", "HYDRA_FULL_ERROR"))


def one_line(error: BaseException) -> tuple[str, int]:
    """The error as one line, and its exit code.

    Examples:
        >>> one_line(RuntimeError("diverged\\n at update 3"))
        ('RuntimeError: diverged at update 3', 1)
    """
    described = describe_error(error)
    if described is not None:
        return described, EXIT_CONFIG
    if is_foreign_checkpoint(error):
        return str(error), EXIT_CONFIG
    unusable = unusable_run_directory(error)
    if unusable is not None:
        return unusable, EXIT_CONFIG
    if isinstance(error, FileWriteError):  # a full device, the file-size limit: the file and the cause
        return str(error), EXIT_FAILED
    if isinstance(error, (RunDirectoryInUse, DamagedFileError)):
        return str(error), EXIT_IN_USE if isinstance(error, RunDirectoryInUse) else EXIT_DAMAGED
    text = " ".join(str(error).split()) or type(error).__name__
    return (text if type(error).__name__ in text else f"{type(error).__name__}: {text}"), EXIT_FAILED


def unusable_run_directory(error: BaseException) -> str | None:
    """The one line for a run directory that cannot be made (Hydra makes it before the job starts):
    a file of that name, a symbolic link to nothing (dangling, or a loop), a path below a file,
    or a name longer than its file system allows (``ENAMETOOLONG``).

    Examples:
        >>> import tempfile
        >>> link = Path(tempfile.mkdtemp(), "run")
        >>> link.symlink_to(link.with_name("gone"))
        >>> unusable_run_directory(FileExistsError(17, "File exists", str(link)))  # doctest: +ELLIPSIS
        '.../run is a symbolic link to nothing (dangling, or a loop): give the job another hydra.run.dir ...'
        >>> print(unusable_run_directory(OSError(36, "File name too long", "/tmp/" + "x" * 300)))  # doctest: +ELLIPSIS
        /tmp/xxx...x: a name of 300 bytes, over its file system's limit of 255 bytes per name: give the job ...
    """
    name = getattr(error, "filename", None)
    another = "give the job another hydra.run.dir (hydra.sweep.dir for a sweep)"
    if isinstance(error, OSError) and error.errno == errno.ENAMETOOLONG and name:
        return f"{name}: {_too_long(Path(name))}: {another}"
    if not isinstance(error, (FileExistsError, NotADirectoryError)) or not name:
        return None
    path = Path(name)
    if path.is_symlink() and not path.exists():
        return f"{path} is a symbolic link to nothing (dangling, or a loop): {another}, or remove the link"
    if path.is_file():
        return f"{path} is a file, not a run directory: {another}"
    above = next((parent for parent in path.parents if parent.is_file()), None)
    if above is not None:
        return f"{path} is below a file ({above}), not in a directory: {another}"
    return None


def _too_long(path: Path) -> str:
    """What makes ``path`` too long, in words: its longest name beyond the file system's limit
    per name (``NAME_MAX``, 255 bytes on most), or else the whole path beyond ``PATH_MAX``."""
    existing = next((parent for parent in path.parents if os.path.isdir(parent)), Path("/"))  # False if too long
    limits = {}
    for limit, default in (("PC_NAME_MAX", 255), ("PC_PATH_MAX", 4096)):
        try:
            limits[limit] = os.pathconf(existing, limit)
        except (OSError, ValueError, AttributeError):  # not known here: the usual value
            limits[limit] = default
    longest = max((len(os.fsencode(part)) for part in path.parts), default=0)
    if longest > limits["PC_NAME_MAX"]:
        return f"a name of {longest} bytes, over its file system's limit of {limits['PC_NAME_MAX']} bytes per name"
    return f"a path of {len(os.fsencode(str(path)))} bytes, over the limit of {limits['PC_PATH_MAX']} bytes per path"


def is_foreign_checkpoint(error: BaseException) -> bool:
    """The run directory holds another config's checkpoint (a sweep relaunched with other values).

    Examples:
        >>> is_foreign_checkpoint(ValueError("lr"))
        False
    """
    checkpoint = sys.modules.get("sde_torchrl.jobs.checkpoint")  # not imported: not its error
    return checkpoint is not None and isinstance(error, checkpoint.CheckpointMismatchError)
