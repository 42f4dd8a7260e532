"""Ctrl-C during training: finish the current update, save a checkpoint, then stop."""

from __future__ import annotations

import logging
import signal
import threading
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C during training: a checkpoint was saved after the last finished update."""

    def __init__(self, updates_done: int, out_dir: Path) -> None:
        self.updates_done, self.out_dir = updates_done, out_dir
        super().__init__(f"interrupted after update {updates_done}; checkpoint saved in {out_dir}")


class DeferredInterrupt:
    """Turns the first Ctrl-C into a request the loop honours after the current update;
    a second Ctrl-C interrupts at once. A no-op outside the main thread.

    Examples:
        >>> with DeferredInterrupt() as interrupt:
        ...     interrupt.requested
        False
    """

    def __init__(self) -> None:
        self.requested = False
        self._previous: Any = None

    def _handle(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        log.warning("Ctrl-C: saving a checkpoint after this update (Ctrl-C again to abort now)")

    def __enter__(self) -> DeferredInterrupt:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
