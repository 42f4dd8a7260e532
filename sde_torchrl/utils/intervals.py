"""Confidence intervals for the numbers the analysis scripts report.

Two kinds, each in one function:

* :func:`bootstrap_interval`: the percentile bootstrap over runs (Efron & Tibshirani 1993,
  ch. 13) of any statistic of one or more independent samples (a mean episode count over runs;
  a speed-up, the ratio of two methods' means; a difference of two means, whose interval
  excluding 0 makes the difference significant at that level). Vectorised with NumPy: all
  resamples are drawn as one ``[resamples, n]`` index array, and deterministic given the seed.
* :func:`binomial_interval`: the Wilson score interval (Wilson 1927) of a proportion ``k / n``
  (the runs, out of ``n``, that catch the ball), which stays inside ``[0, 1]`` and is not empty
  at ``k = 0`` or ``k = n``.

Both return an :class:`Interval` ``(estimate, low, high)``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from statistics import NormalDist
from typing import NamedTuple

import numpy as np


class Interval(NamedTuple):
    """A point estimate and its confidence interval ``[low, high]``.

    Examples:
        >>> Interval(0.5, 0.25, 0.75).high
        0.75
    """

    estimate: float
    low: float
    high: float


def _mean(*samples: np.ndarray) -> np.ndarray:
    """The default statistic: the mean over the last axis of a single sample."""
    if len(samples) != 1:
        raise ValueError(f"the default statistic (the mean) takes one sample, got {len(samples)}: "
                         "pass statistic=... for several")
    return samples[0].mean(-1)


def bootstrap_interval(
    values: Sequence[float] | np.ndarray | tuple[Sequence[float], ...],
    statistic: Callable[..., np.ndarray] = _mean,
    level: float = 0.95,
    resamples: int = 10_000,
    seed: int = 0,
) -> Interval:
    """Percentile bootstrap interval of ``statistic`` over runs.

    Each sample is resampled with replacement, independently of the others, ``resamples`` times;
    the interval is the ``(1 − level)/2`` and ``(1 + level)/2`` quantiles of the statistic over
    the resamples (order statistics, not interpolated: a statistic that is infinite in some
    resamples, such as "episodes until a level is first reached" when it never is, gives an
    infinite end rather than NaN), and the estimate is the statistic of the samples themselves.

    Args:
        values: one sample (a sequence of numbers, one per run), or a tuple of independent
            samples (e.g. two methods' runs), each resampled on its own.
        statistic: maps the (resampled) samples, each an array ``[..., n_i]``, to an array
            ``[...]``: it must reduce the last axis (``lambda a: np.median(a, -1)``;
            ``lambda rex, sde: rex.mean(-1) / sde.mean(-1)``). Defaults to the mean of one sample.
        level: the confidence level, in ``(0, 1)``.
        resamples: number of bootstrap resamples (``>= 1``).
        seed: seed of NumPy's ``default_rng``: the same seed gives the same interval.

    Returns:
        ``Interval(estimate, low, high)``.

    Raises:
        ValueError: an empty sample, a sample that is not one-dimensional, a level outside
            ``(0, 1)`` or ``resamples < 1``.

    Examples:
        >>> bootstrap_interval([1.0, 2.0, 3.0, 4.0], resamples=2000, seed=1)
        Interval(estimate=2.5, low=1.5, high=3.5)
        >>> rex, sde = [9000.0, 9500.0, 10000.0], [800.0, 900.0, 1000.0]
        >>> speedup = bootstrap_interval((rex, sde), lambda r, s: r.mean(-1) / s.mean(-1), seed=1)
        >>> round(speedup.estimate, 2), speedup.low < speedup.estimate < speedup.high
        (10.56, True)
    """
    samples = tuple(np.asarray(v, dtype=float) for v in (values if isinstance(values, tuple) else (values,)))
    for sample in samples:
        if sample.ndim != 1 or sample.size == 0:
            raise ValueError(f"values: each sample must be a non-empty 1-D sequence, got shape {sample.shape}")
    if not 0 < level < 1:
        raise ValueError(f"level={level!r}: a number in (0, 1)")
    if resamples < 1:
        raise ValueError(f"resamples={resamples!r}: an integer >= 1")
    rng = np.random.default_rng(seed)
    resampled = [s[rng.integers(0, s.size, size=(resamples, s.size))] for s in samples]
    replicates = np.asarray(statistic(*resampled), dtype=float)
    low, high = np.quantile(replicates, [(1 - level) / 2, (1 + level) / 2], method="inverted_cdf")
    return Interval(float(statistic(*samples)), float(low), float(high))


def binomial_interval(k: int, n: int, level: float = 0.95) -> Interval:
    """Wilson score interval of the proportion ``p = k / n``.

    With ``z`` the standard normal's ``(1 + level)/2`` quantile (1.96 at 95 %):
    ``centre = (k + z²/2) / (n + z²)`` and
    ``half-width = z / (n + z²) · sqrt(k (n − k) / n + z²/4)``.

    Args:
        k: successes, ``0 <= k <= n``.
        n: trials, ``>= 1``.
        level: the confidence level, in ``(0, 1)``.

    Returns:
        ``Interval(k / n, low, high)``, within ``[0, 1]``.

    Raises:
        ValueError: ``n < 1``, ``k`` outside ``[0, n]`` or a level outside ``(0, 1)``.

    Examples:
        >>> [round(x, 3) for x in binomial_interval(0, 16)]
        [0.0, 0.0, 0.194]
        >>> [round(x, 3) for x in binomial_interval(6, 16)]
        [0.375, 0.185, 0.614]
    """
    if n < 1 or not 0 <= k <= n:
        raise ValueError(f"k={k!r}, n={n!r}: need n >= 1 and 0 <= k <= n")
    if not 0 < level < 1:
        raise ValueError(f"level={level!r}: a number in (0, 1)")
    z = NormalDist().inv_cdf((1 + level) / 2)
    centre = (k + z * z / 2) / (n + z * z)
    half = z / (n + z * z) * np.sqrt(k * (n - k) / n + z * z / 4)
    return Interval(k / n, max(0.0, float(centre - half)), min(1.0, float(centre + half)))
