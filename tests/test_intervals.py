"""sde_torchrl.utils.intervals: Wilson against published values and its exact coverage, the bootstrap
against known cases, its determinism, and its coverage on simulated data."""

from __future__ import annotations

import doctest
import math
from statistics import NormalDist

import numpy as np
import pytest

import sde_torchrl.utils.intervals
from sde_torchrl.utils.intervals import Interval, binomial_interval, bootstrap_interval


def test_doctests():
    result = doctest.testmod(sde_torchrl.utils.intervals, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


@pytest.mark.parametrize(("k", "n", "low", "high"), [
    (0, 16, 0.0, 0.1936),     # the rule of three's neighbour: 3/16 = 0.19
    (6, 16, 0.1848, 0.6136),
    (16, 16, 0.8064, 1.0),    # symmetric to k = 0
    (68, 100, 0.5833, 0.7637),  # the paper's 68/100 good catches
    (7, 100, 0.0343, 0.1374),
])
def test_wilson_matches_known_values(k, n, low, high):
    interval = binomial_interval(k, n)
    assert interval.estimate == k / n
    assert interval.low == pytest.approx(low, abs=6e-4) and interval.high == pytest.approx(high, abs=6e-4)


def test_wilson_level_widens_and_bad_arguments_are_refused():
    assert binomial_interval(6, 16, 0.99).high > binomial_interval(6, 16).high > binomial_interval(6, 16, 0.8).high
    for args in ((-1, 16), (17, 16), (0, 0)):
        with pytest.raises(ValueError, match="n >= 1"):
            binomial_interval(*args)
    with pytest.raises(ValueError, match="level"):
        binomial_interval(1, 2, level=1.0)


@pytest.mark.parametrize("p", [0.1, 0.3, 0.5])
def test_wilson_exact_coverage_is_near_the_level(p):
    n = 40
    coverage = sum(math.comb(n, k) * p**k * (1 - p) ** (n - k)
                   for k in range(n + 1) if binomial_interval(k, n).low <= p <= binomial_interval(k, n).high)
    assert 0.92 <= coverage <= 0.99


def numpy_bootstrap(values, statistic=lambda a: a.mean(-1), level=0.95, resamples=10_000, seed=0) -> Interval:
    """The implementation before SciPy's (the committed pages were written with it)."""
    samples = tuple(np.asarray(v, dtype=float) for v in (values if isinstance(values, tuple) else (values,)))
    rng = np.random.default_rng(seed)
    resampled = [s[rng.integers(0, s.size, size=(resamples, s.size))] for s in samples]
    replicates = np.asarray(statistic(*resampled), dtype=float)
    low, high = np.quantile(replicates, [(1 - level) / 2, (1 + level) / 2], method="inverted_cdf")
    return Interval(float(statistic(*samples)), float(low), float(high))


def wilson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """The Wilson interval's closed form, as written before SciPy's."""
    z = NormalDist().inv_cdf((1 + level) / 2)
    centre = (k + z * z / 2) / (n + z * z)
    half = z / (n + z * z) * math.sqrt(k * (n - k) / n + z * z / 4)
    return max(0.0, centre - half), min(1.0, centre + half)


def ratio(a, b):
    return a.mean(-1) / b.mean(-1)


@pytest.mark.parametrize("case", range(12))
def test_bootstrap_is_the_numpy_bootstrap_to_the_bit(case):
    """SciPy draws the same resamples from the same generator: the committed pages' numbers stay."""
    rng = np.random.default_rng(100 + case)
    one, other = rng.gamma(2.0, 500.0, rng.integers(2, 60)), rng.normal(3.0, 1.0, rng.integers(2, 60))
    one[rng.random(one.size) < 0.1] = np.inf  # runs that never reach a level
    values, statistic = [
        (one, lambda a: a.mean(-1)), (one, lambda a: np.median(a, -1)), ((other, one), ratio),
        ((one, other, other[:1]), lambda a, b, c: np.median(a, -1) - b.mean(-1) * c[..., 0]),
    ][case % 4]
    level, resamples, seed = [(0.95, 10_000, 0), (0.9, 2000, 7), (0.99, 501, 3)][case % 3]
    expected = numpy_bootstrap(values, statistic, level, resamples, seed)
    assert bootstrap_interval(values, statistic, level, resamples, seed) == expected


def test_bootstrap_of_a_sample_of_one_run_is_its_value():
    assert bootstrap_interval([7.0]) == Interval(7.0, 7.0, 7.0) == numpy_bootstrap([7.0])


def test_wilson_is_the_closed_form_and_exact_at_the_ends():
    for level in (0.8, 0.95, 0.99):
        for n in (1, 2, 3, 5, 16, 40, 50, 100):  # 40, 50 and 100 runs: the committed pages
            for k in range(n + 1):
                interval = binomial_interval(k, n, level)
                assert interval[1:] == pytest.approx(wilson(k, n, level), abs=1e-15), (k, n, level)
            assert binomial_interval(0, n, level).low == 0.0 and binomial_interval(n, n, level).high == 1.0


def test_bootstrap_of_a_constant_sample_is_the_constant():
    assert bootstrap_interval([3.0] * 10) == Interval(3.0, 3.0, 3.0)


def test_bootstrap_is_deterministic_given_the_seed_and_varies_with_it():
    values = np.random.default_rng(5).normal(size=30)
    assert bootstrap_interval(values, seed=3) == bootstrap_interval(values, seed=3)
    assert bootstrap_interval(values, seed=3) != bootstrap_interval(values, seed=4)


def test_bootstrap_of_the_mean_has_the_normal_theory_width():
    values = np.random.default_rng(0).normal(10.0, 2.0, size=200)
    interval = bootstrap_interval(values, resamples=20_000)
    half_width = 1.96 * values.std() / math.sqrt(values.size)
    assert interval.estimate == pytest.approx(values.mean())
    assert (interval.high - interval.low) / 2 == pytest.approx(half_width, rel=0.05)


def test_bootstrap_takes_any_reducing_statistic_and_several_samples():
    a, b = [1.0, 2.0, 100.0], [4.0, 5.0, 6.0]
    assert bootstrap_interval(a, lambda x: np.median(x, -1)).estimate == 2.0
    difference = bootstrap_interval((a, b), lambda x, y: x.mean(-1) - y.mean(-1))
    assert difference.estimate == pytest.approx(np.mean(a) - np.mean(b))
    with pytest.raises(ValueError, match="one sample"):
        bootstrap_interval((a, b))


@pytest.mark.parametrize("bad", [[], [[1.0, 2.0]]])
def test_bootstrap_refuses_empty_or_nested_samples(bad):
    with pytest.raises(ValueError, match="1-D"):
        bootstrap_interval(bad)


def test_bootstrap_coverage_on_simulated_runs():
    """30 runs from a skewed distribution (episode counts are), 400 repetitions: the percentile
    interval of the mean covers the true mean about 95 % of the time (a little less: it is
    known to under-cover at small n)."""
    rng = np.random.default_rng(1)
    true_mean = 1000.0
    hits = sum(interval.low <= true_mean <= interval.high for interval in
               (bootstrap_interval(rng.gamma(4.0, true_mean / 4.0, size=30), resamples=2000, seed=i)
                for i in range(400)))
    assert 0.90 <= hits / 400 <= 0.98


def test_bootstrap_difference_detects_a_real_difference_and_not_a_null_one():
    rng = np.random.default_rng(2)
    same = bootstrap_interval((rng.normal(size=30), rng.normal(size=30)), lambda x, y: x.mean(-1) - y.mean(-1))
    shifted = bootstrap_interval((rng.normal(1.0, 1.0, 30), rng.normal(size=30)),
                                 lambda x, y: x.mean(-1) - y.mean(-1))
    assert same.low < 0 < same.high
    assert shifted.low > 0


def test_bootstrap_end_is_infinite_not_nan_when_some_resamples_are():
    never = [100.0, 200.0, float("inf")]
    interval = bootstrap_interval(never, lambda x: np.median(x, -1))
    assert interval.low == 100.0 and interval.high == float("inf")
