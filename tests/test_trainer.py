"""Guards of the training loop (non-finite values), multirun isolation, loggers and progress."""

from __future__ import annotations

import io
import json

import pytest
import torch
from _helpers import build, compose_config, own_stderr_lines, read_rows, run_cli

from sde_torchrl.config.build import run_job
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.trainers.guard import NonFiniteError
from sde_torchrl.trainers.progress import Progress, progress_wanted

# ------------------------------------------------------------------------ non-finite guard


def tamper(trainer, at: int, edit) -> None:
    """Applies ``edit`` (in place) to the episodes collected for update ``at``."""
    collect, calls = trainer.collect, []

    def tampered():
        episodes = collect()
        if len(calls) == at:
            edit(episodes)
        calls.append(1)
        return episodes

    trainer.collect = tampered


def poison_rewards(trainer, at: int, run: int) -> None:
    """Makes one reward of ``run`` NaN in the episodes of update ``at``."""
    tamper(trainer, at, lambda episodes: episodes["next", "reward"].__setitem__((run, 0, 3), float("nan")))


def test_nan_return_names_update_and_run_and_keeps_metrics(tmp_path):
    trainer = build("runs=3", "updates=10", "episodes_per_update=4", "first_run=5")
    poison_rewards(trainer, at=6, run=1)
    with pytest.raises(NonFiniteError) as info:
        trainer.train(tmp_path)
    error = info.value
    assert (error.update, error.what, error.runs) == (6, "return", [6])  # global run index
    message = str(error)
    assert "non-finite return at update 6 in run 6" in message
    assert "largest parameter entry: module.0.module.0.module.weight" in message
    rows = read_rows(tmp_path)
    assert [int(r["update"]) for r in rows] == [k for k in range(6) for _ in range(3)]  # kept
    assert not (tmp_path / "summary.json").exists()


def test_huge_step_names_the_parameter_and_the_runs(tmp_path):
    trainer = build("runs=3", "updates=5", "lr=1e38")
    with pytest.raises(NonFiniteError) as info:
        trainer.train(tmp_path)
    error = info.value
    assert error.what == "parameter" and error.update == 0
    assert error.parameter == "module.0.module.0.module.weight"
    assert error.runs and set(error.runs) <= {0, 1, 2}
    assert "non-finite parameter module.0.module.0.module.weight at update 0 in run" in str(error)


@pytest.mark.parametrize("what", ["gradient", "score"])
def test_nan_gradient_or_score_names_the_parameter(tmp_path, what):
    trainer = build("runs=2", "updates=5", "estimator.max_grad_norm=null")  # a norm bound spreads one NaN to all
    estimate = trainer.estimator.estimate
    if what == "gradient":
        def broken(scores, returns):  # NaN in the σ̂ part (the last entry) of run 1
            gradient, diagnostics = estimate(scores, returns)
            gradient = gradient.clone()
            gradient[1, -1] = float("nan")
            return gradient, diagnostics
        trainer.estimator.estimate = broken
    else:
        def infinite_sample(episodes):  # an infinite action sample: finite returns, non-finite σ̂ score
            episodes[trainer.policy.sample_key][0, 1, 4] = float("inf")
            episodes["next", "reward"][0, 1, 4] = 0.0
        tamper(trainer, 2, infinite_sample)
    with pytest.raises(NonFiniteError) as info:
        trainer.train(tmp_path)
    error = info.value
    assert error.what == what
    assert error.parameter in {"module.0.module.1.sigma_param", "module.0.module.0.module.weight"}
    if what == "gradient":
        assert (error.update, error.runs, error.parameter) == (0, [1], "module.0.module.1.sigma_param")
    else:
        assert (error.update, error.runs) == (2, [0])
    assert f"non-finite {what} of parameter {error.parameter} at update {error.update}" in str(error)
    assert len(read_rows(tmp_path)) == 2 * error.update


def test_overflowing_score_norm_names_its_run(tmp_path):
    """Finite scores whose norm overflows float32 (seen with an unbounded gradient) name the run."""
    trainer = build("runs=3", "updates=5")
    # a finite action sample so far off that the scores square past float32
    tamper(trainer, 1, lambda episodes: episodes[trainer.policy.sample_key].__setitem__((2, 0, 4), 1e17))
    with pytest.raises(NonFiniteError) as info:
        trainer.train(tmp_path)
    error = info.value
    assert (error.what, error.update, error.runs) == ("score norm", 1, [2])
    assert "non-finite score norm at update 1 in run 2" in str(error)


@pytest.mark.e2e
def test_nan_run_on_the_command_line_fails_in_one_line(tmp_path):
    result = run_cli("+experiment=minimize", "updates=5", "runs=2", "lr=1e38", "logger=none", run_dir=tmp_path)
    assert result.returncode == 1
    lines = own_stderr_lines(result.stderr)
    assert len(lines) == 1 and lines[0].startswith("error: NonFiniteError: non-finite parameter "), lines
    assert "at update 0" in lines[0]
    assert (tmp_path / "error.txt").read_text().startswith("NonFiniteError: non-finite parameter")
    assert (tmp_path / "metrics.csv").exists() and not (tmp_path / "summary.json").exists()


# ------------------------------------------------------------------------ multirun isolation


@pytest.mark.e2e
def test_failing_job_in_a_sweep_keeps_the_others(tmp_path):
    # Job 0 diverges at its first update (a runtime failure); job 1 must still run and finish.
    result = run_cli("+experiment=minimize", "updates=6", "runs=2", "logger=none", "lr=1e38,0.005",
                     run_dir=tmp_path, multirun=True)
    assert result.returncode == 1, result.stderr[-2000:]
    lines = own_stderr_lines(result.stderr)
    assert len(lines) == 1 and lines[0].startswith("error: NonFiniteError"), lines
    assert "lr=1e+38" in lines[0] and str(tmp_path / "0" / "error.txt") in lines[0]
    assert (tmp_path / "0" / "error.txt").is_file()  # failed: the error recorded, no summary
    assert not (tmp_path / "0" / "summary.json").exists()
    summary = json.loads((tmp_path / "1" / "summary.json").read_text())  # complete
    assert summary["updates_done"] == 6 and len(summary["final_return"]) == 2
    assert summary["config"]["lr"] == 0.005
    assert not (tmp_path / "1" / "error.txt").exists()
    assert len(read_rows(tmp_path / "1")) == 12


# ------------------------------------------------------------------------ loggers, progress


def test_tensorboard_logger_writes_event_files(tmp_path):
    pytest.importorskip("tensorboard")
    cfg = compose_config("+experiment=minimize", "logger=tensorboard", "updates=3")
    run_job(validate(cfg), str(tmp_path), {"env": "minimize"})
    events = list((tmp_path / "sde_torchrl").glob("events.out.tfevents.*"))
    assert events and events[0].stat().st_size > 0


def test_wandb_logger_runs_offline(tmp_path, monkeypatch):
    pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_SILENT", "true")
    monkeypatch.setenv("WANDB_DIR", str(tmp_path))
    cfg = compose_config("+experiment=minimize", "logger=wandb", "updates=2")
    assert cfg.logger.offline is True
    run_job(validate(cfg), str(tmp_path), {"env": "minimize"})
    runs = list(tmp_path.glob("**/offline-run-*/run-*.wandb"))
    assert runs and runs[0].stat().st_size > 0


class FakeTTY(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.parametrize("setting, multirun, tty, expected", [
    (None, False, True, True), (None, False, False, False), (None, True, True, False),
    (True, True, False, True), (False, False, True, False),
])
def test_progress_only_on_a_terminal_outside_multirun(setting, multirun, tty, expected):
    stream = FakeTTY() if tty else io.StringIO()
    assert progress_wanted(setting, multirun, stream) is expected


def test_progress_bar_shows_return_and_speed(tmp_path, capsys):
    pytest.importorskip("tqdm")
    trainer = build("updates=3", "eval_period=0")
    trainer.train(tmp_path, progress=True)
    err = capsys.readouterr().err
    assert "3/3" in err and "ret=" in err and "steps_s=" in err
    bar = Progress(total=2, enabled=False)
    bar.step(-1.0, 10.0)  # disabled: silent
    bar.close()
    assert capsys.readouterr().err == ""
    assert torch.isfinite(torch.tensor(0.0))


@pytest.mark.parametrize("kind", ["sum", "mean"])
def test_reported_returns_and_threshold_use_the_estimators_return_definition(tmp_path, kind):
    """return_mean, eval_return and episodes_to_threshold follow estimator.episode_return; the
    summary records it. With the sum over T = 15 steps the start lies 15× the mean's."""
    trainer = build("updates=1", "runs=2", "r_lim=-1e9", f"estimator.episode_return={kind}")
    episodes = trainer.collect()
    stats = trainer.estimate(episodes, 0)
    rewards = episodes["next", "reward"].squeeze(-1)
    expected = rewards.sum(-1) if kind == "sum" else rewards.mean(-1)
    torch.testing.assert_close(stats["return_mean"], expected.mean(-1))
    summary = build("updates=1", "runs=2", "r_lim=-1e9", f"estimator.episode_return={kind}").train(tmp_path)
    assert summary["episode_return"] == kind
    assert summary["episodes_to_threshold"] == [10, 10]
    eval_return = float(read_rows(tmp_path)[0]["eval_return"])
    assert eval_return < -5 if kind == "sum" else -5 < eval_return < 0
