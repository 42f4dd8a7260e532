"""What the analysis scripts' figures and tables share: one line style per method, a saved
matplotlib figure, and the two-sample statistics their bootstrap intervals are of.

Examples:
    >>> style("SDE + GPOMDP") == style("sde+gpomdp") == {"color": "tab:green", "ls": "-."}
    True
    >>> import numpy as np
    >>> float(ratio_of_means(np.array([4.0, 8.0]), np.array([1.0, 2.0])))
    4.0
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

#: One colour and line style per method, in every figure.
STYLES = {"sde": {"color": "tab:blue", "ls": "-"}, "rex": {"color": "tab:red", "ls": "--"},
          "sde+gpomdp": {"color": "tab:green", "ls": "-."}, "pgpe": {"color": "tab:purple", "ls": ":"}}


def style(method: str) -> dict[str, str]:
    """The line style of a method, by key (``sde+gpomdp``, ``sde_gpomdp``) or label
    (``SDE + GPOMDP``); ``{}`` (matplotlib's own cycle) for another one."""
    return STYLES.get(method.lower().replace(" + ", "+").replace("_", "+"), {})


@contextmanager
def saved_figure(path: Path, *grid: int, **subplots: Any) -> Iterator[tuple[Any, Any]]:
    """``plt.subplots(*grid, **subplots)`` for the block inside, then laid out tightly and saved
    to ``path`` at 110 dpi (headless: the Agg backend), and closed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(*grid, **subplots)
    try:
        yield fig, axes
        fig.tight_layout()
        fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)


def ratio_of_means(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``mean(a) / mean(b)`` over the last axis: a speed-up, or one method's result over another's."""
    return a.mean(-1) / b.mean(-1)


def difference_of_means(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``mean(a) − mean(b)`` over the last axis: the difference of two methods' fractions."""
    return a.mean(-1) - b.mean(-1)


def bounds(interval: tuple[float, float, float]) -> list[float]:
    """``[low, high]`` of an :class:`~sde_torchrl.utils.intervals.Interval`, as the JSON files hold it."""
    return [interval[1], interval[2]]
