"""Limits before work (issue 26, item 3): a job's memory is estimated from its sizes and a job
that cannot fit is refused at once, naming the estimate and the setting; a slow first update
says what it is doing."""

from __future__ import annotations

import logging
import re
import time

import pytest
from _helpers import REPO, build, compose_config, own_stderr_lines, run_cli

from sde_torchrl.config.schemas import describe_error, validate
from sde_torchrl.jobs.resources import GB, estimate_memory, launcher_request
from sde_torchrl.trainers import trainer as trainer_module


@pytest.mark.parametrize("override, key", [("runs=1000000", "runs"),
                                           ("episodes_per_update=10000000", "episodes_per_update"),
                                           ("env.episode_length=100000000", "env.episode_length")])
def test_absurd_sizes_are_refused_at_once_in_one_line(tmp_path, override, key):
    start = time.monotonic()
    result = run_cli("+experiment=minimize", override, run_dir=tmp_path / "run")
    elapsed = time.monotonic() - start
    assert result.returncode == 2, result.stderr[-2000:]
    lines = own_stderr_lines(result.stderr)
    assert len(lines) == 1 and lines[0].startswith(f"error: {override}: the job would hold about "), lines
    assert "GB this machine has available; lower runs" in lines[0]
    assert elapsed < 4, f"{elapsed:.1f} s"  # the check itself is arithmetic; the rest is Python starting up
    assert not (tmp_path / "run" / "metrics.csv").exists()


def test_max_memory_gb_sets_the_limit():
    ballcatch = ("+experiment=ballcatch", "runs=5")
    assert estimate_memory(validate(compose_config(*ballcatch))).total_gb == pytest.approx(1.0, abs=0.05)
    with pytest.raises(Exception) as info:
        validate(compose_config(*ballcatch, "max_memory_gb=0.8"))
    assert describe_error(info.value).startswith("runs=5: the job would hold about 1.0 GB (estimate), more than "
                                                 "max_memory_gb=0.8; ")
    validate(compose_config(*ballcatch, "max_memory_gb=1.2"))


#: Max RSS of ``+experiment=ballcatch runs=N`` measured on this machine (``/usr/bin/time -v``, 2-3 updates).
MEASURED_GB = {5: 1.01, 20: 2.84, 50: 6.52}


@pytest.mark.parametrize("runs, measured_gb", MEASURED_GB.items())
def test_ballcatch_estimates_grow_with_the_worlds(runs, measured_gb):
    """Max RSS measured on this machine (``/usr/bin/time -v``, 2-3 updates): within 30 %."""
    conf = validate(compose_config("+experiment=ballcatch", f"runs={runs}", "max_memory_gb=1000"))
    estimate = estimate_memory(conf)
    assert estimate.worlds == runs * 4 * 28e6  # one training world and three evaluation worlds per run
    if measured_gb is not None:
        assert estimate.total / GB == pytest.approx(measured_gb, rel=0.3)


def test_a_slow_first_update_says_what_it_is_doing(monkeypatch, caplog, tmp_path):
    monkeypatch.setattr(trainer_module, "FIRST_UPDATE_NOTICE_S", 0.0)
    trainer = build("runs=2", "updates=2", "episodes_per_update=4")
    original = trainer.update
    monkeypatch.setattr(trainer, "update", lambda episodes, k: (time.sleep(0.3), original(episodes, k))[1])
    with caplog.at_level(logging.INFO, logger="sde_torchrl.trainers.trainer"):
        trainer.train(tmp_path)
    notices = [r.getMessage() for r in caplog.records if "still running" in r.getMessage()]
    assert notices == ["update 1 of 2 still running after 0 s: collecting 4 episodes of 15 steps for each of 2 "
                       "runs, then estimating the gradient"]


def test_the_guides_memory_figures_are_the_estimates_and_the_measurements():
    """The figures ``docs/guide/guarantees.md`` quotes are the estimator's (and the measurements above)."""
    text = " ".join((REPO / "docs" / "guide" / "guarantees.md").read_text().split())
    runs = sorted(MEASURED_GB)
    estimates = [estimate_memory(validate(compose_config("+experiment=ballcatch", f"runs={n}", "max_memory_gb=1000")))
                 .total / GB for n in runs]
    quoted = (f"{' / '.join(f'{e:.1f}' for e in estimates)} GB estimated for {' / '.join(map(str, runs))} runs, "
              f"{' / '.join(f'{MEASURED_GB[n]:.2f}' for n in runs)} GB measured")
    assert quoted in text
    request = launcher_request(validate(compose_config("+experiment=ballcatch", "runs=50", "max_memory_gb=1000")))
    shard = re.search(r"a 50-run ball-catching shard: (\d+) GB, (\d+) min", text)
    assert shard and (int(shard[1]), int(shard[2])) == (request["mem_gb"], request["timeout_min"])
