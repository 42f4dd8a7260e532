"""Per-run random streams.

Independent runs trained side by side must each own a random stream, so that run ``r`` of a
batched job draws exactly what a single job with run ``r``'s seed would draw. A stream is a
``torch.Generator`` seeded from ``(seed, run, purpose)``; the purposes keep, for example, the
explorer's noise apart from the environment's so that changing one never shifts the other.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from sde_torchrl.utils.checks import positive_int

#: Purposes that get their own stream in every run (``final_eval``: the episodes on which a job's
#: final and best policies are checked at its end, apart from training and periodic evaluation).
STREAMS = ("init", "explore", "env", "eval_env", "final_eval")


def run_seed(seed: int, run: int, stream: str) -> int:
    """Derives the 63-bit seed of one run's stream from the job seed.

    Args:
        seed: the job's seed (``seed=`` on the command line).
        run: global index of the run (``first_run + r``).
        stream: one of :data:`STREAMS`.

    Returns:
        A seed for ``torch.Generator.manual_seed``.

    Raises:
        ValueError: for an unknown stream or a negative seed or run.
    """
    if stream not in STREAMS:
        raise ValueError(f"unknown random stream {stream!r}; expected one of {STREAMS}")
    if seed < 0 or run < 0:
        raise ValueError(f"seed and run must be non-negative, got seed={seed}, run={run}")
    entropy = [seed, run, STREAMS.index(stream)]
    return int(np.random.SeedSequence(entropy).generate_state(1, np.uint64)[0] >> np.uint64(1))


class RunStreams:
    """Independent standard-normal streams, one per run, served in batched slices.

    Each run owns a ``torch.Generator`` seeded by :func:`run_seed`. Draws are served from a
    per-run buffer refilled ``chunk`` numbers at a time, so a request for ``[runs, *shape]``
    costs one tensor slice, and one generator call per run only at a refill. Every run consumes
    its stream in the same pattern whatever the number of runs beside it: run ``r`` of a batched
    job draws exactly what a one-run job with ``first_run = r`` draws.

    Args:
        seed: the job's seed.
        runs: number of runs in this process.
        stream: one of :data:`STREAMS`.
        first_run: global index of the first run here (shards of a sweep use different ones).
        chunk: numbers drawn per run at each refill.

    Examples:
        >>> streams = RunStreams(seed=0, runs=3, stream="explore")
        >>> streams.normal((3, 2)).shape
        torch.Size([3, 2])
    """

    def __init__(self, seed: int, runs: int, stream: str, first_run: int = 0, chunk: int = 4096) -> None:
        self.runs, self.chunk = positive_int("runs", runs), chunk
        self.generators = [
            torch.Generator().manual_seed(run_seed(seed, first_run + r, stream)) for r in range(runs)
        ]
        self._buffer = torch.empty(runs, 0)

    def normal(self, shape: Sequence[int]) -> torch.Tensor:
        """Standard normal samples of ``shape``; ``shape[0]`` must be the number of runs."""
        shape = tuple(shape)
        if not shape or shape[0] != self.runs:
            raise ValueError(f"leading dimension of {shape} must equal the number of runs ({self.runs})")
        n = math.prod(shape[1:])
        if self._buffer.shape[1] < n:
            with torch.inference_mode(False):  # a buffer that autograd may read, wherever it is refilled
                fresh = torch.stack([torch.randn(max(self.chunk, n), generator=g) for g in self.generators])
                self._buffer = torch.cat([self._buffer, fresh], dim=1)
        out, self._buffer = self._buffer[:, :n], self._buffer[:, n:]
        return out.reshape(shape)

    def uniform(self, shape: Sequence[int]) -> torch.Tensor:
        """Uniform samples on ``(0, 1)``: the normal CDF of :meth:`normal` draws."""
        return 0.5 * torch.special.erfc(-self.normal(shape) / math.sqrt(2.0))

    def state_dict(self) -> dict:
        """Generator states and the unserved buffer: all it takes to resume the streams."""
        return {"generators": [g.get_state() for g in self.generators], "buffer": self._buffer.clone()}

    def load_state_dict(self, state: dict) -> None:
        """Restores what :meth:`state_dict` saved."""
        if len(state["generators"]) != self.runs:
            raise ValueError(f"state holds {len(state['generators'])} runs, these streams {self.runs}")
        for g, g_state in zip(self.generators, state["generators"], strict=True):
            g.set_state(g_state)
        self._buffer = state["buffer"].clone()


def draw_normal(shape: Sequence[int], streams: RunStreams | None = None) -> torch.Tensor:
    """Standard normal samples from per-run ``streams``, or torch's global generator."""
    return torch.randn(tuple(shape)) if streams is None else streams.normal(shape)


def draw_uniform(shape: Sequence[int], streams: RunStreams | None = None) -> torch.Tensor:
    """Uniform samples on ``[0, 1)`` from per-run ``streams``, or torch's global generator."""
    return torch.rand(tuple(shape)) if streams is None else streams.uniform(shape)
