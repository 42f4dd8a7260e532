"""analysis/benchmarks/bench_sac/: both sides' rounds and gradient steps come from the job's one
config, and the command line refuses bad values by name."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from analysis.benchmarks.bench_ppo import iterations
from analysis.benchmarks.bench_sac import cli, rounds, update_speed

#: Small minibatches: the timed code, not its speed, is under test.
SMALL = ("algorithm.compile=false", "algorithm.batch_size=64")


@pytest.mark.parametrize("argv, message", [
    (["update-speed", "job", "--updates", "0"], "--updates and --rounds must be positive"),
    (["update-speed", "job", "--env", "pendulum"], "invalid choice"),
    (["update-speed", "sb3_tuned"], "invalid choice"),
    (["speed", "job", "sb3", "--rounds", "4"], "--rounds must be at least 5"),
    (["speed", "job", "--repeats", "0"], "--repeats at least 1"),
    (["run", "--method", "sde"], "invalid choice"),
])
def test_bad_command_lines_are_refused_by_name(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.parametrize("side", [rounds.job_rounds, rounds.sb3_rounds], ids=["job", "sb3"])
def test_each_side_times_its_own_rounds(side):
    """``bench_sac speed``: ``+experiment=sac_mountaincar``'s trainer and SB3's SAC at its settings,
    one round (32 env steps, 32 gradient steps) at a time, each round's end in wall and CPU seconds."""
    ends = np.asarray(side(4, SMALL))
    assert ends.shape == (4, 2) and (np.diff(ends[:, 0]) > 0).all() and (ends[:, 1] > 0).all()


def test_sb3s_side_is_built_from_the_jobs_config():
    """The SB3 model that ``speed`` and ``update-speed`` time has the job's settings, noise included."""
    from analysis.benchmarks.gsde_table.sb3 import build_model, sb3_settings

    for overrides, use_sde in (((), True), (("explorer=gaussian",), False)):
        conf = rounds.job_config(overrides)
        model, env = build_model(sb3_settings(conf), seed=0)
        assert model.use_sde is use_sde and model.batch_size == conf.algorithm.batch_size
        assert model.train_freq.frequency == conf.algorithm.train_freq and model.gradient_steps == 32
        assert model.policy.actor.latent_pi[0].out_features == conf.actor.hidden[0]
        env.close()


def test_update_speed_fills_both_buffers_then_times_the_gradient_steps():
    """The job's first update only collects (``learning_starts``), then each call is ``updates`` steps."""
    job = update_speed.job_steps("sac_mountaincar", SMALL, 2)
    job()
    sb3 = update_speed.sb3_steps("sac_mountaincar", SMALL[1:], 2)
    sb3()
    fill = update_speed._fill_overrides("sac_mountaincar")
    assert fill[0] == "algorithm.learning_starts=1024" and fill[1] == "algorithm.rounds_per_update=32"


def test_update_speed_writes_its_table(tmp_path):
    out = tmp_path / "speed.md"
    assert cli.main(["update-speed", "job+eager", "sb3", "--updates", "2", "--rounds", "1", "--profile",
                     "--out", str(out)]) == 0
    text = out.read_text()
    assert text.startswith("Written by `python -m analysis.benchmarks.bench_sac update-speed job+eager sb3")
    rows = [line for line in text.splitlines() if line.startswith("| job+eager |") or line.startswith("| sb3 |")]
    assert len(rows) == 2 and rows[1].endswith("| 1.00 |")
    assert "| backward passes |" in text and "| fresh loss noise |" in text


@pytest.mark.parametrize("script, side", [
    ("bench_sac", lambda: rounds.sb3_rounds(4)),
    ("bench_sac", lambda: update_speed.sb3_steps("sac_mountaincar", (), 2)),
    ("bench_ppo", lambda: iterations.train_sb3(2)),
], ids=["sac-speed", "sac-update-speed", "ppo-speed"])
def test_without_stable_baselines3_the_sb3_variants_say_how_to_install_it(monkeypatch, script, side):
    monkeypatch.setitem(sys.modules, "stable_baselines3", None)  # import stable_baselines3 raises ImportError
    with pytest.raises(SystemExit, match=rf"{script}: the sb3 variants need .*pip install -e '\.\[bench\]'"):
        side()
