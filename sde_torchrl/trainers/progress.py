"""A progress bar for interactive training: updates done, mean return, env steps per second.

Shown only where someone watches: on a terminal (``stderr`` is a TTY) and not under a Hydra
multirun, whose jobs' bars would interleave. Uses ``tqdm`` when installed, else a one-line
counter rewritten in place.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO


def progress_wanted(setting: bool | None, multirun: bool, stream: TextIO | None = None) -> bool:
    """Whether to show a bar: ``setting`` if given, else only on a terminal outside multirun."""
    if setting is not None:
        return bool(setting)
    stream = sys.stderr if stream is None else stream
    return not multirun and bool(getattr(stream, "isatty", lambda: False)())


class Progress:
    """Updates done out of ``total`` with the latest mean return and env steps per second.

    Args:
        total: number of updates of the job.
        initial: updates already done (a resumed job).
        enabled: ``False`` makes every method a no-op.

    Examples:
        >>> bar = Progress(total=3, enabled=False)
        >>> bar.step(return_mean=-1.0, steps_per_s=1000.0)
        >>> bar.close()
    """

    def __init__(self, total: int, initial: int = 0, enabled: bool = True) -> None:
        self.total, self.done, self.enabled = total, initial, enabled
        self._bar: Any = None
        if enabled:
            try:
                from tqdm.auto import tqdm
            except ImportError:  # the fallback below
                tqdm = None
            if tqdm is not None:
                self._bar = tqdm(total=total, initial=initial, unit="update", dynamic_ncols=True,
                                 file=sys.stderr)

    def step(self, return_mean: float, steps_per_s: float) -> None:
        """Marks one more update done."""
        if not self.enabled:
            return
        self.done += 1
        if self._bar is not None:
            self._bar.set_postfix(ret=f"{return_mean:.3f}", steps_s=f"{steps_per_s:.0f}", refresh=False)
            self._bar.update(1)
        else:
            sys.stderr.write(f"\rupdate {self.done}/{self.total}  return {return_mean:.3f}  "
                             f"{steps_per_s:.0f} steps/s")
            sys.stderr.flush()

    def close(self) -> None:
        """Ends the bar (leaves the final line on screen)."""
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.close()
        else:
            sys.stderr.write("\n")
        self.enabled = False


class RateMeter:
    """Env steps per second since construction."""

    def __init__(self) -> None:
        self.start, self.steps = time.perf_counter(), 0

    def add(self, steps: int) -> float:
        """Counts ``steps`` more and returns the rate so far."""
        self.steps += steps
        return self.steps / max(time.perf_counter() - self.start, 1e-9)
