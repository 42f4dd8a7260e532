"""Per-run random streams: independent, reproducible, and the same for a run whether it is
trained alone or beside others."""

from __future__ import annotations

import pytest
import torch

from sde_torchrl.utils.rng import RunStreams, run_seed


def _draws(runs, first_run, chunk=7):
    streams = RunStreams(seed=3, runs=runs, stream="explore", first_run=first_run, chunk=chunk)
    # uneven request sizes that straddle refills, including one larger than a chunk
    return torch.cat([streams.normal((runs, k)) for k in (3, 5, 1, 11, 4, 2)], dim=1)


def test_run_r_of_a_batch_draws_what_a_single_run_draws():
    batched = _draws(runs=4, first_run=0)
    for r in range(4):
        torch.testing.assert_close(batched[r], _draws(runs=1, first_run=r)[0], rtol=0, atol=0)


def test_runs_and_streams_are_distinct_and_seeds_reproducible():
    batched = _draws(runs=3, first_run=0)
    assert not torch.equal(batched[0], batched[1])
    assert torch.equal(batched, _draws(runs=3, first_run=0))
    assert len({run_seed(0, r, s) for r in range(5) for s in ("init", "explore", "env")}) == 15


def test_uniform_draws_are_uniform():
    u = RunStreams(seed=0, runs=2, stream="init").uniform((2, 50_000))
    assert float(u.min()) > 0 and float(u.max()) < 1
    assert abs(float(u.mean()) - 0.5) < 0.01 and abs(float(u.var()) - 1 / 12) < 0.005


def test_state_dict_resumes_the_streams_exactly():
    streams = RunStreams(seed=1, runs=2, stream="env", chunk=5)
    streams.normal((2, 3))
    saved = streams.state_dict()
    expected = streams.normal((2, 9))
    resumed = RunStreams(seed=99, runs=2, stream="env", chunk=5)
    resumed.load_state_dict(saved)
    assert torch.equal(resumed.normal((2, 9)), expected)


def test_bad_requests_are_rejected():
    with pytest.raises(ValueError, match="number of runs"):
        RunStreams(seed=0, runs=2, stream="env").normal((3, 4))
    with pytest.raises(ValueError, match="stream"):
        RunStreams(seed=0, runs=2, stream="nonsense")
    with pytest.raises(ValueError, match="non-negative"):
        run_seed(-1, 0, "env")
