"""metrics.csv's columns, declared once (sde_torchrl/jobs/metrics.py): the header, the rows, the
parser, the checkpoint's record and the logger keys all follow from the declaration."""

from __future__ import annotations

import csv
import io

import pytest
import torch

from sde_torchrl.jobs.metrics import (
    METRIC_FIELDS,
    METRICS,
    RECORDS,
    REQUIRED_FIELDS,
    MetricRow,
    MetricsFormatError,
    csv_lines,
    logged_values,
    metric_rows,
    parse_metrics,
    recorded_rows,
    update_statistics,
)
from sde_torchrl.trainers.report import Reporter
from sde_torchrl.trainers.summary import LoopState

#: The columns of every metrics.csv written so far, in order (committed run directories, the guides).
HEADER = ("run", "update", "episodes", "return_mean", "eval_return", "grad_norm", "sigma_min", "sigma_max",
          "weight_max")


def _statistics(update: int, runs: int = 3, evaluated: bool = False) -> dict:
    generator = torch.Generator().manual_seed(update)
    recorded = {"return_mean": torch.randn(runs, generator=generator),
                "grad_norm": torch.rand(runs, generator=generator),
                "exploration": torch.rand(3, runs, generator=generator)}
    return update_statistics(4, update, 10 * (update + 1), recorded,
                             torch.randn(runs, generator=generator) if evaluated else None)


def _parse(lines: list[bytes]) -> list[MetricRow]:
    return parse_metrics(csv.reader(io.StringIO(b"".join(lines).decode(), newline="")))


def test_the_header_is_the_declaration_in_order():
    """The columns written so far keep their order; a metric added later comes after them."""
    assert METRIC_FIELDS == tuple(metric.name for metric in METRICS) == MetricRow._fields
    assert METRIC_FIELDS[:len(HEADER)] == HEADER
    assert REQUIRED_FIELDS == HEADER[:5]
    assert not any(metric.required for metric in METRICS[len(HEADER):])  # older files lack their columns
    assert csv_lines([]) == [(",".join(METRIC_FIELDS) + "\r\n").encode()]


def test_rows_parse_back_to_themselves_and_to_the_same_bytes():
    rows = [row for k in range(4) for row in metric_rows(_statistics(k, evaluated=k % 2 == 1))]
    lines = csv_lines(rows)
    parsed = _parse(lines)
    assert parsed == rows and all(isinstance(row, MetricRow) for row in parsed)
    assert [row.eval_return is None for row in parsed[::3]] == [True, False, True, False]
    assert [(row.run, row.update) for row in parsed[:4]] == [(4, 0), (5, 0), (6, 0), (4, 1)]
    assert csv_lines(parsed) == lines


def test_a_file_written_before_the_last_columns_reads_them_as_none():
    rows = metric_rows(_statistics(0, evaluated=True))
    lines = csv_lines(rows, METRIC_FIELDS[:6])
    assert lines[0] == b"run,update,episodes,return_mean,eval_return,grad_norm\r\n"
    parsed = _parse(lines)
    assert [row[:6] for row in parsed] == [row[:6] for row in rows]
    assert all(value is None for row in parsed for value in row[6:])
    assert csv_lines(parsed, METRIC_FIELDS[:6]) == lines


def test_columns_are_found_by_name_in_any_order():
    rows = metric_rows(_statistics(2, evaluated=True))
    order = list(reversed(METRIC_FIELDS))
    text = io.StringIO(newline="")
    writer = csv.writer(text)
    writer.writerow(order)
    writer.writerows([getattr(row, name) for name in order] for row in rows)
    assert parse_metrics(csv.reader(io.StringIO(text.getvalue(), newline=""))) == rows


@pytest.mark.parametrize(("header", "cells", "says"), [
    pytest.param("run,update,episodes,return_mean,eval_return,loss", "0,0,5,-1.5,,2",
                 "its column 'loss' is not a metric (the metrics are run, update, episodes, return_mean, eval_return, ",
                 id="unknown"),
    pytest.param("run,update,episodes,eval_return", "0,0,5,",
                 "it has no column 'return_mean' (every metrics.csv has run, update, episodes, return_mean, "
                 "eval_return)",
                 id="missing"),
    pytest.param("run,update,episodes,return_mean,eval_return,run", "0,0,5,-1.5,,0", "its column 'run' appears twice",
                 id="repeated"),
    pytest.param("run,update,episodes,return_mean,eval_return", "0,0,5,-1.5", "its row 1 has 4 cells, its header 5",
                 id="short-row"),
])
def test_a_column_that_is_not_declared_or_missing_is_named(tmp_path, header, cells, says):
    from sde_torchrl.jobs.run_dir import read_metrics

    path = tmp_path / "metrics.csv"
    path.write_text(f"{header}\r\n{cells}\r\n")
    with pytest.raises(MetricsFormatError) as error:
        read_metrics(path)
    assert str(error.value).startswith(f"{path} cannot be read as metrics: {says}"), str(error.value)


def test_the_checkpoint_record_is_the_one_loop_state_keeps():
    """RECORDS names a checkpoint's per-update records as they were named before the declaration
    (older checkpoints resume), and a loop record gives back the rows the updates wrote."""
    assert [(r.statistic, r.key) for r in RECORDS] == [
        ("return_mean", "returns"), ("grad_norm", "grad_norms"), ("exploration", "explorations")]
    state, written = LoopState(update=0, reached=torch.zeros(3, dtype=torch.bool)), []
    for k in range(3):
        statistics = _statistics(k, evaluated=k == 2)
        state.add({name: statistics[name] for name in ("return_mean", "grad_norm", "exploration")})
        if statistics["eval_return"] is not None:
            state.evals[k] = statistics["eval_return"]
        state.update = k + 1
        written += metric_rows(statistics)
    loop = state.state_dict()
    assert list(loop)[:5] == ["update", "reached", "returns", "grad_norms", "explorations"]
    assert loop["explorations"].shape == (3, 3, 3)
    assert recorded_rows(loop, 4, lambda k: 10 * (k + 1)) == written
    assert recorded_rows(LoopState.from_state_dict(loop).record(), 4, lambda k: 10 * (k + 1)) == written
    empty = LoopState(update=0, reached=torch.zeros(2, dtype=torch.bool)).state_dict()
    assert [tuple(empty[r.key].shape) for r in RECORDS] == [(0, 2), (0, 2), (0, 3, 2)]


def test_the_logged_keys_are_the_declared_ones():
    class Logger:
        def __init__(self):
            self.logged = []

        def log_scalar(self, key, value, step):
            self.logged.append((key, value, step))

    declared = [metric.log_key for metric in METRICS if metric.log_key is not None]
    assert declared[:2] == ["return_mean", "eval_return"]  # the TorchRL CSV logger's files of every job so far
    logger, statistics = Logger(), _statistics(1, evaluated=True)
    Reporter(logger, updates=2, done=0, steps_per_update=10).update(1, 20, statistics)
    assert [key for key, _, _ in logger.logged] == declared and {step for _, _, step in logger.logged} == {20}
    assert logger.logged[:2] == [("return_mean", float(statistics["return_mean"].mean()), 20),
                                 ("eval_return", float(statistics["eval_return"].mean()), 20)]
    assert "eval_return" not in logged_values(_statistics(0))  # no evaluation: not logged
