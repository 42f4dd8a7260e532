"""Per-run random streams.

Independent runs trained side by side must each own a random stream, so that run ``r`` of a
batched job draws exactly what a single job with run ``r``'s seed would draw. A stream is a
``torch.Generator`` seeded from ``(seed, run, purpose)``; the purposes keep, for example, the
explorer's noise apart from the environment's so that changing one never shifts the other.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

#: Purposes that get their own stream in every run.
STREAMS = ("init", "explore", "env", "eval_env")


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


def run_generators(seed: int, runs: int, stream: str, first_run: int = 0) -> list[torch.Generator]:
    """One seeded generator per run for ``stream``.

    Args:
        seed: the job's seed.
        runs: number of runs in this process.
        stream: one of :data:`STREAMS`.
        first_run: global index of the first run here (shards of a sweep use different ones).

    Returns:
        ``runs`` generators.

    Examples:
        >>> gens = run_generators(seed=0, runs=3, stream="explore")
        >>> draw_normal((3, 2), gens).shape
        torch.Size([3, 2])
    """
    return [
        torch.Generator().manual_seed(run_seed(seed, first_run + r, stream)) for r in range(runs)
    ]


def draw_normal(
    shape: Sequence[int], generators: Sequence[torch.Generator] | None = None
) -> torch.Tensor:
    """Standard normal samples, one independent stream per leading index.

    Args:
        shape: output shape. With ``generators``, ``shape[0]`` must equal their number.
        generators: per-run generators, or ``None`` for torch's global generator.

    Returns:
        A float32 tensor of ``shape``.

    Raises:
        ValueError: if ``shape[0]`` does not match the number of generators.
    """
    return _draw(torch.randn, shape, generators)


def draw_uniform(
    shape: Sequence[int], generators: Sequence[torch.Generator] | None = None
) -> torch.Tensor:
    """Uniform samples on ``[0, 1)``, one stream per leading index (see :func:`draw_normal`)."""
    return _draw(torch.rand, shape, generators)


def _draw(sampler, shape: Sequence[int], generators: Sequence[torch.Generator] | None):
    shape = tuple(shape)
    if generators is None:
        return sampler(shape)
    if not shape or shape[0] != len(generators):
        raise ValueError(
            f"leading dimension of {shape} must equal the number of run generators "
            f"({len(generators)})"
        )
    return torch.stack([sampler(shape[1:], generator=g) for g in generators])
