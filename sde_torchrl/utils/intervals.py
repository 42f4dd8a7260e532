"""Confidence intervals for the numbers the analysis scripts report.

Two kinds, each in one function, both computed by SciPy:

* :func:`bootstrap_interval`: the percentile bootstrap over runs (Efron & Tibshirani 1993,
  ch. 13) of any statistic of one or more independent samples (a mean episode count over runs;
  a speed-up, the ratio of two methods' means; a difference of two means, whose interval
  excluding 0 makes the difference significant at that level). The resamples are
  :func:`scipy.stats.bootstrap`'s (deterministic given the seed); the ends are order statistics
  of the bootstrap distribution (Efron & Tibshirani's percentile interval), not SciPy's
  interpolated ones, which warn when some resamples' statistic is infinite.
* :func:`binomial_interval`: the Wilson score interval (Wilson 1927) of a proportion ``k / n``
  (the runs, out of ``n``, that catch the ball), which stays inside ``[0, 1]`` and is not empty
  at ``k = 0`` or ``k = n``: :meth:`scipy.stats.binomtest`'s ``proportion_ci(method="wilson")``.

Both return an :class:`Interval` ``(estimate, low, high)``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
from scipy import stats


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

    Each sample is resampled with replacement, independently of the others, ``resamples`` times
    (:func:`scipy.stats.bootstrap`, its generator ``np.random.default_rng(seed)``); the interval
    is the ``(1 − level)/2`` and ``(1 + level)/2`` quantiles of the statistic over the resamples
    (order statistics, not interpolated as SciPy's own ends are; a statistic that is infinite in
    some resamples, such as "episodes until a level is first reached" when it never is, gives an
    infinite end), and the estimate is the statistic of the samples themselves.
    A sample of one run is the same in every resample.

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
    estimate = float(statistic(*samples))
    # A one-run sample resamples to itself (and draws nothing from the generator); SciPy wants two or more.
    varying = [i for i, sample in enumerate(samples) if sample.size > 1]
    if not varying:
        return Interval(estimate, estimate, estimate)

    def on_resamples(*resampled: np.ndarray, axis: int = -1) -> np.ndarray:
        drawn = dict(zip(varying, resampled, strict=True))
        shape = (*resampled[0].shape[:-1], 1)
        arguments = [drawn[i] if i in drawn else np.broadcast_to(s, shape) for i, s in enumerate(samples)]
        return np.asarray(statistic(*arguments), dtype=float)

    with warnings.catch_warnings(), np.errstate(invalid="ignore"):  # SciPy's own ends (unused) warn at inf
        warnings.simplefilter("ignore", stats.DegenerateDataWarning)
        result = stats.bootstrap([samples[i] for i in varying], on_resamples, n_resamples=resamples,
                                 vectorized=True, method="percentile", confidence_level=level,
                                 rng=np.random.default_rng(seed))
    low, high = np.quantile(result.bootstrap_distribution, [(1 - level) / 2, (1 + level) / 2], method="inverted_cdf")
    return Interval(estimate, float(low), float(high))


def binomial_interval(k: int, n: int, level: float = 0.95) -> Interval:
    """Wilson score interval of the proportion ``p = k / n``, as SciPy computes it
    (``scipy.stats.binomtest(k, n).proportion_ci(level, method="wilson")``: exactly 0 at ``k = 0``
    and 1 at ``k = n``).

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
    interval = stats.binomtest(k, n).proportion_ci(confidence_level=level, method="wilson")
    return Interval(k / n, float(interval.low), float(interval.high))
