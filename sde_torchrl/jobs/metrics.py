"""The metrics a job records, declared once: the columns of ``metrics.csv``, in order.

Each :class:`Metric` of :data:`METRICS` says how its per-run value is computed from an update's
statistics (:func:`update_statistics`), how it is read back from a CSV cell, and the key (if
any) under which its run-averaged curve is logged. Everything else follows from the declaration:

- the header, :data:`METRIC_FIELDS`, and the typed row, :class:`MetricRow`;
- the rows of an update, :func:`metric_rows`, and those a checkpoint's record holds,
  :func:`recorded_rows` (what a resumed job checks ``metrics.csv`` against and rebuilds it from);
- the lines of the file, :func:`csv_lines`, and its parser, :func:`parse_metrics` (by column
  index, one parser per column);
- the logger's values, :func:`logged_values`.

The statistics a job keeps for every update (in :class:`~sde_torchrl.trainers.summary.LoopState`
and in a checkpoint's ``loop``) are declared beside them, :data:`RECORDS`.
"""

from __future__ import annotations

import csv
import gc
import io
from collections import namedtuple
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from operator import itemgetter
from typing import Any, NamedTuple

import torch


def number(cell: str) -> float | None:
    """A float cell that may be empty (no value: ``None``).

    Examples:
        >>> number("-1.5"), number("")
        (-1.5, None)
    """
    return float(cell) if cell else None


@dataclass(frozen=True)
class Metric:
    """One column of ``metrics.csv``.

    Attributes:
        name: the column, and the field of :class:`MetricRow`.
        compute: the update's statistics (:func:`update_statistics`) → the column's values, one
            per run: a tensor ``[runs]``, a sequence, one value for every run, or ``None`` (no
            value this update: an empty cell).
        parse: a CSV cell → the value (``int``, ``float``, :func:`number` for a cell that may be
            empty).
        log_key: the key its run-averaged curve is logged under by the job's TorchRL logger
            (``log_scalar``; a ``/`` namespaces it, ``"train/..."``); ``None``: not logged.
        required: every ``metrics.csv`` has the column; a metric added later is not required, so
            that the files written before it still read (its value is then ``None``).

    Examples:
        >>> metric = Metric("grad_norm", itemgetter("grad_norm"), number)
        >>> metric.compute({"grad_norm": torch.tensor([0.5])}), metric.parse("0.5")
        (tensor([0.5000]), 0.5)
    """

    name: str
    compute: Callable[[Mapping[str, Any]], Any]
    parse: Callable[[str], Any]
    log_key: str | None = None
    required: bool = False


class Record(NamedTuple):
    """A statistic a job keeps for every update: in its loop state and in its checkpoint.

    Attributes:
        statistic: its name in the update's statistics (what the trainer's update returns).
        key: its name in a checkpoint's ``loop`` (the per-update values stacked, ``[updates, *shape, runs]``).
        shape: the dimensions of one update's value before the runs' (``()``: ``[runs]``).

    Examples:
        >>> Record("exploration", "explorations", (3,)).shape
        (3,)
    """

    statistic: str
    key: str
    shape: tuple[int, ...] = ()


#: The statistics kept per update (the evaluations, made every ``eval_period`` updates, are kept
#: apart, by update: a checkpoint's ``evals``).
RECORDS = (
    Record("return_mean", "returns"),
    Record("grad_norm", "grad_norms"),
    Record("exploration", "explorations", (3,)),
)

#: ``metrics.csv``'s columns, in order (see :func:`update_statistics` for the statistics). A new
#: metric computed from :data:`RECORDS` is a :class:`Metric` added at the end (the files written
#: before it lack its column, and still read); one that needs a statistic the update does not yet
#: return also needs that statistic returned by the trainer's update and a :class:`Record` of it,
#: which changes the checkpoint's record (:data:`~sde_torchrl.jobs.checkpoint.FORMAT`).
METRICS = (
    Metric("run", lambda s: range(s["first_run"], s["first_run"] + s["runs"]), int, required=True),
    Metric("update", itemgetter("update"), int, required=True),
    Metric("episodes", itemgetter("episodes"), int, required=True),
    Metric("return_mean", itemgetter("return_mean"), float, log_key="return_mean", required=True),
    Metric("eval_return", itemgetter("eval_return"), number, log_key="eval_return", required=True),
    Metric("grad_norm", itemgetter("grad_norm"), number),
    # the exploration state after the update (sde_torchrl.trainers.summary.exploration_state)
    Metric("sigma_min", lambda s: s["exploration"][0], number),
    Metric("sigma_max", lambda s: s["exploration"][1], number),
    Metric("weight_max", lambda s: s["exploration"][2], number),
)
#: The header of ``metrics.csv``.
METRIC_FIELDS = tuple(metric.name for metric in METRICS)
#: The columns every ``metrics.csv`` has (the first ones).
REQUIRED_FIELDS = tuple(metric.name for metric in METRICS if metric.required)
#: The exploration state's columns (:func:`~sde_torchrl.trainers.summary.exploration_state`).
EXPLORATION_FIELDS = ("sigma_min", "sigma_max", "weight_max")
if METRIC_FIELDS[:len(REQUIRED_FIELDS)] != REQUIRED_FIELDS or len(set(METRIC_FIELDS)) != len(METRICS):
    raise ValueError(f"METRICS: the required metrics come first, each name once: {METRIC_FIELDS}")


def _may_be_empty(metric: Metric) -> bool:
    try:
        return metric.parse("") is None
    except ValueError:
        return False


def _trailing_defaults() -> tuple[None, ...]:
    """``None`` for the last fields of :class:`MetricRow` whose cell may be empty."""
    count = 0
    for metric in reversed(METRICS):
        if not _may_be_empty(metric):
            break
        count += 1
    return (None,) * count


MetricRow = namedtuple("MetricRow", METRIC_FIELDS, defaults=_trailing_defaults())
MetricRow.__doc__ = """One ``metrics.csv`` row, typed: one run after one update (a field per :data:`METRICS` entry).

A value is ``None`` where its cell is empty (``eval_return`` of an update without an evaluation)
or its column is missing (a metric added after the file was written); the last fields whose
cell may be empty default to ``None``.

Examples:
    >>> row = MetricRow(run=0, update=3, episodes=40, return_mean=-1.0, eval_return=None)
    >>> row.eval_return is None, row.sigma_min is None
    (True, True)
"""


class MetricsFormatError(ValueError):
    """``metrics.csv``'s columns are not :data:`METRICS`' (an unknown, missing or repeated
    column), or a row does not have the header's number of cells.

    Examples:
        >>> str(MetricsFormatError("metrics.csv", "it has no column 'run'"))
        "metrics.csv cannot be read as metrics: it has no column 'run'"
    """

    def __init__(self, source: str, problem: str) -> None:
        super().__init__(f"{source} cannot be read as metrics: {problem}")


def update_statistics(
    first_run: int, update: int, episodes: int, recorded: Mapping[str, torch.Tensor],
    eval_return: torch.Tensor | None,
) -> dict[str, Any]:
    """An update's statistics, what the metrics are computed from.

    Args:
        first_run: global index of the job's first run (``first_run``).
        update: the update, 0-based (``update``).
        episodes: episodes each run has collected by its end (``episodes``).
        recorded: what the trainer's update returned (on the CPU): the :data:`RECORDS`
            statistics, per run, ``return_mean`` ``[runs]``, ``grad_norm`` ``[runs]``,
            ``exploration`` ``[3, runs]``, and any other.
        eval_return: mean deterministic return per run ``[runs]``, or ``None`` (not evaluated).

    Returns:
        ``recorded`` with the entries named above and ``runs`` (the number of runs).

    Examples:
        >>> stats = update_statistics(2, 0, 10, {"return_mean": torch.tensor([-1.5, -2.0])}, None)
        >>> stats["runs"], stats["eval_return"]
        (2, None)
    """
    return {**recorded, "first_run": first_run, "update": update, "episodes": episodes,
            "eval_return": eval_return, "runs": len(recorded["return_mean"])}


def _column(values: Any, runs: int) -> Sequence[Any]:
    """A metric's computed values as one Python value per run."""
    if values is None:
        return (None,) * runs
    if isinstance(values, torch.Tensor):
        values = values.tolist()  # Python numbers, one call per column
    if isinstance(values, (int, float)):
        return (values,) * runs
    return values


def metric_rows(statistics: Mapping[str, Any]) -> list[MetricRow]:
    """The ``metrics.csv`` rows of one update, one per run.

    Args:
        statistics: the update's statistics (:func:`update_statistics`).

    Raises:
        ValueError: a metric gave another number of values than there are runs.

    Examples:
        >>> stats = update_statistics(2, 0, 10, {"return_mean": torch.tensor([-1.5]), "grad_norm": torch.tensor([0.25]),
        ...                                      "exploration": torch.tensor([[0.125], [0.5], [2.0]])}, None)
        >>> metric_rows(stats)  # doctest: +NORMALIZE_WHITESPACE
        [MetricRow(run=2, update=0, episodes=10, return_mean=-1.5, eval_return=None, grad_norm=0.25,
                   sigma_min=0.125, sigma_max=0.5, weight_max=2.0)]
    """
    runs = statistics["runs"]
    columns = [_column(metric.compute(statistics), runs) for metric in METRICS]
    return [MetricRow._make(values) for values in zip(*columns, strict=True)]


def recorded_rows(loop: Mapping[str, Any], first_run: int, episodes: Callable[[int], int]) -> list[MetricRow]:
    """The ``metrics.csv`` rows a loop record holds (a checkpoint's ``loop``, or
    :meth:`~sde_torchrl.trainers.summary.LoopState.record`): every update up to ``update``.

    Args:
        loop: ``update``, ``evals`` (update → values) and each of :data:`RECORDS` under its key,
            indexable by update.
        first_run: global index of the job's first run.
        episodes: update → episodes each run has collected by its end.

    Examples:
        >>> loop = {"update": 1, "returns": torch.tensor([[-1.0]]), "evals": {},
        ...         "grad_norms": torch.tensor([[2.0]]), "explorations": torch.tensor([[[0.5], [0.5], [1.0]]])}
        >>> [(row.run, row.episodes, row.grad_norm) for row in recorded_rows(loop, 3, lambda k: 10 * (k + 1))]
        [(3, 10, 2.0)]
    """
    return [row for k in range(loop["update"])
            for row in metric_rows(update_statistics(first_run, k, episodes(k),
                                                     {r.statistic: loop[r.key][k] for r in RECORDS},
                                                     loop["evals"].get(k)))]


def logged_values(statistics: Mapping[str, Any]) -> dict[str, float]:
    """The logger's values of an update: each logged metric's mean over the runs, under its
    ``log_key``, in :data:`METRICS` order (a metric without a value this update is left out).

    Examples:
        >>> logged_values(update_statistics(0, 0, 5, {"return_mean": torch.tensor([-1.0, -2.0])}, None))
        {'return_mean': -1.5}
    """
    logged = {}
    for metric in METRICS:
        if metric.log_key is None:
            continue
        values = metric.compute(statistics)
        if values is None:
            continue
        if isinstance(values, torch.Tensor):
            logged[metric.log_key] = float(values.mean())
        else:
            values = _column(values, statistics["runs"])
            logged[metric.log_key] = float(sum(values) / len(values))
    return logged


def csv_lines(rows: Iterable[MetricRow], fields: Sequence[str] = METRIC_FIELDS) -> list[bytes]:
    """The lines of a ``metrics.csv`` holding ``rows``, header first, byte for byte as the job
    writes them (``fields``: the first columns only, those of a file written before the last ones
    were recorded).

    Raises:
        ValueError: ``fields`` are not the first columns of :data:`METRIC_FIELDS`.

    Examples:
        >>> rows = metric_rows(update_statistics(0, 3, 40, {
        ...     "return_mean": torch.tensor([-1.0]), "grad_norm": torch.tensor([2.0]),
        ...     "exploration": torch.tensor([[0.25], [0.5], [1.0]])}, torch.tensor([-0.5])))
        >>> for line in csv_lines(rows):
        ...     print(line.decode().rstrip())
        run,update,episodes,return_mean,eval_return,grad_norm,sigma_min,sigma_max,weight_max
        0,3,40,-1.0,-0.5,2.0,0.25,0.5,1.0
        >>> [line.decode().rstrip() for line in csv_lines(rows, METRIC_FIELDS[:5])]
        ['run,update,episodes,return_mean,eval_return', '0,3,40,-1.0,-0.5']
    """
    fields = tuple(fields)
    if fields != METRIC_FIELDS[:len(fields)]:
        raise ValueError(f"{','.join(fields)} are not the first columns of {','.join(METRIC_FIELDS)}")
    text = io.StringIO(newline="")
    writer = csv.writer(text)  # None is an empty cell
    writer.writerow(fields)
    writer.writerows(rows if len(fields) == len(METRIC_FIELDS) else (row[:len(fields)] for row in rows))
    return text.getvalue().encode().splitlines(keepends=True)


def parse_metrics(lines: Iterator[list[str]], source: str = "metrics.csv") -> list[MetricRow]:
    """Typed rows from a ``metrics.csv``'s cells (a ``csv.reader``), header first, in file order:
    each column parsed by its metric's ``parse``, found by its index in the header, so that
    a file written before a metric was added (its column missing) reads with ``None`` for it.

    Args:
        lines: the file's cells, line by line, header first (none: no rows).
        source: the file's name, for the errors.

    Raises:
        MetricsFormatError: a column is not a metric, a required one is missing, one is repeated,
            or a row has another number of cells than the header.
        ValueError: a cell is not a number of its column's type.

    Examples:
        >>> [row.return_mean for row in parse_metrics(csv.reader(["run,update,episodes,return_mean,eval_return",
        ...                                                       "0,0,5,-1.5,"]))]
        [-1.5]
        >>> parse_metrics(csv.reader(["run,update,episodes,return_mean,eval_return,loss", "0,0,5,-1.5,,2"]))
        ... # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        sde_torchrl.jobs.metrics.MetricsFormatError: metrics.csv ...: its column 'loss' is not a metric (...)
    """
    with _collection_paused():
        return _typed_rows(lines, source)


@contextmanager
def _collection_paused() -> Iterator[None]:
    """Python's cyclic garbage collector held off for the block (restored as it was).

    Parsing a file creates a tuple per row and per cell list, none of them in a cycle; with the
    collector on, each of its passes also walks every row parsed before (the other files of a
    sweep, held by the reader), so reading a sweep's files slowed down as it went.

    Examples:
        >>> with _collection_paused():
        ...     gc.isenabled()
        False
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _typed_rows(lines: Iterator[list[str]], source: str) -> list[MetricRow]:
    """:func:`parse_metrics`' work, with the collector held off by the caller."""
    header = next(lines, None)
    if header is None:
        return []
    index = {}
    for i, name in enumerate(header):
        if name not in METRIC_FIELDS:
            raise MetricsFormatError(source, f"its column {name!r} is not a metric (the metrics are "
                                             f"{', '.join(METRIC_FIELDS)})")
        if name in index:
            raise MetricsFormatError(source, f"its column {name!r} appears twice")
        index[name] = i
    missing = [name for name in REQUIRED_FIELDS if name not in index]
    if missing:
        raise MetricsFormatError(source, f"it has no column {missing[0]!r} (every metrics.csv has "
                                         f"{', '.join(REQUIRED_FIELDS)})")
    cells = [row for row in lines if row]  # a blank line is no row
    for i, row in enumerate(cells):
        if len(row) != len(header):
            raise MetricsFormatError(source, f"its row {i + 1} has {len(row)} cells, its header {len(header)}")
    if not cells:
        return []
    columns = list(zip(*cells, strict=True))  # each row has the header's cells
    parsed = [list(map(metric.parse, columns[index[metric.name]])) if metric.name in index else [None] * len(cells)
              for metric in METRICS]
    return list(map(MetricRow, *parsed))
