"""What the analysis scripts' figures and tables share: one line style per method, a saved
matplotlib figure, the two-sample statistics their bootstrap intervals are of, and the writer of a
page's JSON (its floats rounded to :data:`PAGE_DIGITS` significant digits).

Examples:
    >>> style("SDE + GPOMDP") == style("sde+gpomdp") == {"color": "tab:green", "ls": "-."}
    True
    >>> import numpy as np
    >>> float(ratio_of_means(np.array([4.0, 8.0]), np.array([1.0, 2.0])))
    4.0
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

#: Significant digits of every float in a page's JSON. The pages print at most four (from the
#: unrounded numbers), so six keep two to spare, while a simulated float's last bits, which differ
#: between machines (pybullet, float64), are not written; on a rounding boundary they can still move
#: the sixth digit, so ``tests/study/test_pages.py`` compares numbers to one unit in it (relative 1e-5).
PAGE_DIGITS = 6

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


def rounded(value: Any, digits: int = PAGE_DIGITS) -> Any:
    """``value`` with every finite float in it (also in nested dicts, lists and tuples; a tuple
    becomes a list, as JSON writes it) rounded to ``digits`` significant digits; NaN and ±inf,
    integers, booleans, strings, ``None`` and dict keys as they are.

    Examples:
        >>> rounded({"x": -0.09085822555217142, "runs": 3, "ok": True, "xs": (1 / 3, 2.5e-7, float("nan"))})
        {'x': -0.0908582, 'runs': 3, 'ok': True, 'xs': [0.333333, 2.5e-07, nan]}
        >>> rounded(8618.888888888889), rounded(0.1), rounded(float("-inf")), rounded(2 / 3, digits=2)
        (8618.89, 0.1, -inf, 0.67)
    """
    if isinstance(value, float):
        return float(f"{value:.{digits}g}") if math.isfinite(value) else value
    if isinstance(value, dict):
        return {key: rounded(item, digits) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [rounded(item, digits) for item in value]
    return value


def write_page_json(path: Path, numbers: Any, indent: int = 1) -> None:
    """Writes ``numbers`` to ``path`` as a page's JSON: every float :func:`rounded` to
    :data:`PAGE_DIGITS` significant digits, indented by ``indent``, ending with a newline; NaN and
    ±inf as :func:`json.dumps` writes them (``NaN``, ``Infinity``, ``-Infinity``).

    Examples:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     write_page_json(Path(folder) / "page.json", {"mean": 2 / 3, "low": float("nan")}, indent=None)
        ...     (Path(folder) / "page.json").read_text()
        '{"mean": 0.666667, "low": NaN}\\n'
    """
    path.write_text(json.dumps(rounded(numbers), indent=indent) + "\n")
