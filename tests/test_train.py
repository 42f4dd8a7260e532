"""End-to-end tests of ``train.py`` (Hydra entry point) and of ``build_trainer``.

Starting ``train.py`` costs several seconds of imports, so the command-line jobs the selected
tests need are started once, two at a time, in a module-scoped fixture (``jobs``) and the
tests only wait for their results; the Python-API tests run in this process meanwhile. The
command-line tests are marked ``e2e`` (``python -m pytest -m e2e``), left out of the default run.
"""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch
from _helpers import REPO, build
from omegaconf import OmegaConf

from sde_torchrl import expln

METRIC_FIELDS = ["run", "update", "episodes", "return_mean", "eval_return", "grad_norm", "sigma_min", "sigma_max",
                 "weight_max"]
SUMMARY_KEYS = {
    "explorer", "estimator", "env", "actor", "seed", "runs", "first_run", "settings",
    "initial_return", "final_return", "final_eval_return", "episodes_to_threshold",
    "final_parameters", "env_steps", "wall_s",
}
PER_RUN_KEYS = ("initial_return", "final_return", "final_eval_return", "episodes_to_threshold")

# The short budget of the schema and determinism jobs. 25 updates with the experiment's
# eval_period=10 put evaluations at updates 9, 19 and (the last) 24.
SHORT = ["updates=25", "runs=2"]
SHORT_UPDATES, SHORT_RUNS, EVAL_PERIOD, EPISODES, EPISODE_LENGTH = 25, 2, 10, 10, 15
TINY = ["updates=4", "runs=1", "logger=none"]


# --------------------------------------------------------------------------------------------
# Command-line jobs
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Job:
    """A ``train.py`` invocation: ``multirun`` jobs write into ``hydra.sweep.dir``."""

    overrides: tuple[str, ...]
    multirun: bool = False


@dataclass
class JobResult:
    returncode: int
    stdout: str
    stderr: str
    wall_s: float
    out_dir: Path

    def check(self) -> JobResult:
        assert self.returncode == 0, (
            f"train.py exited with {self.returncode}\nstdout:\n{self.stdout[-3000:]}\n"
            f"stderr:\n{self.stderr[-3000:]}"
        )
        return self


# In start order: the long default job first so that it is never queued behind the others.
JOBS = {
    "default": Job(("+experiment=minimize",)),
    "short": Job(("+experiment=minimize", *SHORT)),
    "seeds": Job(("+experiment=minimize", *SHORT, "seed=0,1"), multirun=True),
    "rex_gauss_enac": Job(("+experiment=minimize", "explorer=rex,sde_gauss", "estimator=enac",
                           *TINY), multirun=True),
    "every_n": Job(("+experiment=minimize", "explorer=every_n", "explorer.every_n=3", *TINY)),
    "nonsense": Job(("+experiment=minimize", "explorer=nonsense", *TINY)),
}
# Jobs whose wall time is asserted: the others run at a lower CPU priority.
TIMED_JOBS = {"default"}
# The tests that wait for these jobs are end-to-end (``-m e2e``), all on one pytest-xdist worker:
# on two, each worker's ``jobs`` fixture would start its own copy of the jobs.
ON_ONE_WORKER = pytest.mark.xdist_group("train_jobs")
# Which jobs each test waits for (only the selected tests' jobs are started).
JOBS_BY_TEST = {
    "test_short_job_writes_documented_outputs": ("short",),
    "test_checkpoint_loads_into_a_fresh_policy": ("short",),
    "test_default_experiment_learns_within_a_minute": ("default",),
    "test_same_seed_reproduces_and_other_seed_differs": ("short", "seeds"),
    "test_group_choices_combine_with_experiment": ("rex_gauss_enac",),
    "test_every_n_choice_with_its_option": ("every_n",),
    "test_unknown_group_option_fails": ("nonsense",),
}


def run_train(job: Job, out_dir: Path, niceness: int = 0) -> JobResult:
    """Runs ``train.py`` from the repository root with its output in ``out_dir``.

    ``niceness`` lowers the job's CPU priority so that a timed job running alongside is not
    slowed down by it.
    """
    dir_key = "hydra.sweep.dir" if job.multirun else "hydra.run.dir"
    cmd = [sys.executable, "train.py", *(["-m"] if job.multirun else []), *job.overrides,
           f"{dir_key}={out_dir}"]
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    if niceness:
        try:
            os.setpriority(os.PRIO_PROCESS, proc.pid, niceness)
        except OSError:  # already exited, or not permitted: run at normal priority
            pass
    try:
        stdout, stderr = proc.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        proc.kill()
        stdout, stderr = proc.communicate()
    return JobResult(proc.returncode, stdout, stderr, time.perf_counter() - start, out_dir)


class Jobs:
    """The module's ``train.py`` jobs, run in the background two at a time."""

    def __init__(self, base: Path, names: list[str]) -> None:
        self.base = base
        self.pool = ThreadPoolExecutor(max_workers=2)
        self.futures: dict[str, Future] = {}
        for name in names:
            self._submit(name)

    def _submit(self, name: str) -> None:
        niceness = 0 if name in TIMED_JOBS else 10
        self.futures[name] = self.pool.submit(run_train, JOBS[name], self.base / name, niceness)

    def __getitem__(self, name: str) -> JobResult:
        if name not in self.futures:  # a test not listed in JOBS_BY_TEST
            self._submit(name)
        return self.futures[name].result()


@pytest.fixture(scope="module")
def jobs(request, tmp_path_factory):
    here = Path(__file__).resolve()
    selected = {
        name
        for item in request.session.items
        if Path(item.path).resolve() == here
        for name in JOBS_BY_TEST.get(getattr(item, "originalname", item.name), ())
    }
    runner = Jobs(tmp_path_factory.mktemp("train_jobs"), [n for n in JOBS if n in selected])
    yield runner
    runner.pool.shutdown(wait=True, cancel_futures=True)


def read_metrics(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path / "metrics.csv", newline="") as f:
        reader = csv.DictReader(f)
        return list(reader.fieldnames or []), list(reader)


def read_summary(path: Path) -> dict:
    return json.loads((path / "summary.json").read_text())


def sweep_summaries(result: JobResult) -> list[dict]:
    """Summaries of a multirun's jobs, in job order (sub-directories 0, 1, ...)."""
    dirs = sorted((d for d in result.out_dir.iterdir() if d.name.isdigit()), key=lambda d: int(d.name))
    return [read_summary(d) for d in dirs]


def eval_updates(updates: int, period: int) -> set[int]:
    return {k for k in range(updates) if (k + 1) % period == 0} | {updates - 1}


# --------------------------------------------------------------------------------------------
# 1. A short job end to end: the documented outputs
# --------------------------------------------------------------------------------------------

@pytest.mark.e2e
@ON_ONE_WORKER
def test_short_job_writes_documented_outputs(jobs):
    out = jobs["short"].check().out_dir

    fields, rows = read_metrics(out)
    assert fields == METRIC_FIELDS
    assert len(rows) == SHORT_RUNS * SHORT_UPDATES
    expected_order = [(k, r) for k in range(SHORT_UPDATES) for r in range(SHORT_RUNS)]
    assert [(int(row["update"]), int(row["run"])) for row in rows] == expected_order
    evals = eval_updates(SHORT_UPDATES, EVAL_PERIOD)
    assert evals == {9, 19, 24}
    for row in rows:
        k = int(row["update"])
        assert int(row["episodes"]) == (k + 1) * EPISODES
        assert math.isfinite(float(row["return_mean"])) and float(row["return_mean"]) < 0
        assert math.isfinite(float(row["grad_norm"])) and float(row["grad_norm"]) >= 0
        if k in evals:
            assert row["eval_return"] != "", f"missing eval_return at update {k}"
            assert math.isfinite(float(row["eval_return"]))
        else:
            assert row["eval_return"] == "", f"unexpected eval_return at update {k}"

    summary = read_summary(out)
    assert SUMMARY_KEYS <= set(summary), SUMMARY_KEYS - set(summary)
    assert (summary["env"], summary["actor"], summary["explorer"], summary["estimator"]) == (
        "minimize", "linear", "sde", "reinforce")
    assert summary["seed"] == 0 and summary["first_run"] == 0
    assert isinstance(summary["runs"], int) and not isinstance(summary["runs"], bool)
    assert summary["runs"] == SHORT_RUNS
    for key in PER_RUN_KEYS:
        assert isinstance(summary[key], list) and len(summary[key]) == SHORT_RUNS, key
    expected_settings = {
        "updates": SHORT_UPDATES, "episodes_per_update": EPISODES, "episode_length": EPISODE_LENGTH,
        "eval_period": EVAL_PERIOD, "eval_episodes": 5, "r_lim": -1.8, "first_run": 0,
    }
    assert {k: summary["settings"].get(k) for k in expected_settings} == expected_settings
    assert sorted(summary["final_parameters"]) == ["module.0.module.0.module.weight", "module.0.module.1.sigma_param"]
    for name, values in summary["final_parameters"].items():
        assert len(values) == SHORT_RUNS and all(len(v) == 1 for v in values), name
    assert summary["env_steps"] == SHORT_UPDATES * EPISODES * EPISODE_LENGTH * SHORT_RUNS == 7500
    assert isinstance(summary["wall_s"], float) and summary["wall_s"] > 0

    # The summary agrees with the metrics it was computed from.
    by_update = {}
    for row in rows:
        by_update.setdefault(int(row["update"]), []).append(row)
    first, last = by_update[0], by_update[SHORT_UPDATES - 1]
    assert summary["initial_return"] == pytest.approx([float(r["return_mean"]) for r in first])
    assert summary["final_return"] == pytest.approx([float(r["return_mean"]) for r in last])
    assert summary["final_eval_return"] == pytest.approx([float(r["eval_return"]) for r in last])
    # The exploration state after the last update: σ̂ = expln(p) of the one element, |θ|.
    final = summary["final_parameters"]
    for run, row in enumerate(last):
        sigma = float(expln(torch.tensor(final["module.0.module.1.sigma_param"][run][0])))
        assert float(row["sigma_min"]) == float(row["sigma_max"]) == pytest.approx(sigma, rel=1e-6)
        weight = final["module.0.module.0.module.weight"][run][0]
        assert float(row["weight_max"]) == pytest.approx(abs(weight), rel=1e-6)
    for run in range(SHORT_RUNS):
        above = [k for k in range(SHORT_UPDATES) if float(by_update[k][run]["return_mean"]) > -1.8]
        expected = (above[0] + 1) * EPISODES if above else None
        assert summary["episodes_to_threshold"][run] == expected

    # TorchRL's CSV logger: run-averaged curves indexed by episodes.
    scalars = out / "sde_torchrl" / "scalars"
    with open(scalars / "return_mean.csv") as f:
        logged = [line.split(",") for line in f.read().split()]
    assert [int(step) for step, _ in logged] == [(k + 1) * EPISODES for k in range(SHORT_UPDATES)]
    mean_returns = [sum(float(r["return_mean"]) for r in by_update[k]) / SHORT_RUNS
                    for k in range(SHORT_UPDATES)]
    assert [float(v) for _, v in logged] == pytest.approx(mean_returns, rel=1e-5)
    with open(scalars / "eval_return.csv") as f:
        logged_eval = [line.split(",") for line in f.read().split()]
    assert [int(step) for step, _ in logged_eval] == [(k + 1) * EPISODES for k in sorted(evals)]


@pytest.mark.e2e
@ON_ONE_WORKER
def test_checkpoint_loads_into_a_fresh_policy(jobs):
    out = jobs["short"].check().out_dir
    checkpoint = torch.load(out / "checkpoint.pt")
    assert checkpoint["updates"] == SHORT_UPDATES
    state = checkpoint["policy"]
    assert all(isinstance(v, torch.Tensor) for v in state.values())

    trainer = build(*SHORT)
    trainer.policy.load_state_dict(state)  # strict: same keys and shapes as a fresh policy
    trained = {name: p.detach().reshape(SHORT_RUNS, -1).tolist()
               for name, p in trainer.policy.named_parameters()}
    summary = read_summary(out)
    assert trained.keys() == summary["final_parameters"].keys() == state.keys()
    for name, values in summary["final_parameters"].items():
        assert trained[name] == values, name  # exact: the checkpoint holds the final weights
    # Training moved the controller away from its initial -2.
    assert all(v[0] != -2.0 for v in trained["module.0.module.0.module.weight"])


# --------------------------------------------------------------------------------------------
# 2. The default experiment learns
# --------------------------------------------------------------------------------------------

@pytest.mark.e2e
@ON_ONE_WORKER
def test_default_experiment_learns_within_a_minute(jobs):
    result = jobs["default"].check()
    print(f"default experiment: {result.wall_s:.1f} s wall")
    assert result.wall_s < 60, f"default experiment took {result.wall_s:.1f} s"
    summary = read_summary(result.out_dir)
    assert summary["runs"] == 4
    assert summary["settings"]["updates"] == 300
    assert summary["env_steps"] == 300 * EPISODES * EPISODE_LENGTH * 4
    _, rows = read_metrics(result.out_dir)
    assert len(rows) == 4 * 300
    for run, (first, final) in enumerate(zip(summary["initial_return"], summary["final_return"], strict=True)):
        assert final > first, f"run {run}: return {first} -> {final}"
    weights = [v for k, v in summary["final_parameters"].items() if k.endswith("weight")]
    assert len(weights) == 1
    for run, (w,) in enumerate(weights[0]):
        assert -12 < w < -2.5, f"run {run}: controller weight {w}"


# --------------------------------------------------------------------------------------------
# 3. Reproducibility
# --------------------------------------------------------------------------------------------

@pytest.mark.e2e
@ON_ONE_WORKER
def test_same_seed_reproduces_and_other_seed_differs(jobs):
    single = jobs["short"].check().out_dir
    sweep = jobs["seeds"].check()
    seed0, seed1 = sweep.out_dir / "0", sweep.out_dir / "1"

    def summary_without_wall(path: Path) -> dict:
        summary = read_summary(path)
        assert isinstance(summary.pop("wall_s"), float)
        return summary

    # Same seed in another process (and as job 0 of a sweep): identical outputs.
    reference = summary_without_wall(single)
    assert summary_without_wall(seed0) == reference
    assert (seed0 / "metrics.csv").read_text() == (single / "metrics.csv").read_text()

    # Another seed: different exploration, returns and parameters.
    other = summary_without_wall(seed1)
    assert other["seed"] == 1
    assert other["initial_return"] != reference["initial_return"]
    assert other["final_return"] != reference["final_return"]
    assert other["final_parameters"] != reference["final_parameters"]
    assert (seed1 / "metrics.csv").read_text() != (single / "metrics.csv").read_text()


# --------------------------------------------------------------------------------------------
# 4. Run r of a batched job equals a single run with first_run=r
# --------------------------------------------------------------------------------------------

def test_batched_run_equals_single_run_with_first_run(tmp_path):
    budget = ("updates=10", "episodes_per_update=5", "seed=3")
    batched = build("runs=3", *budget).train(tmp_path / "batched")
    single = build("runs=1", "first_run=1", *budget).train(tmp_path / "single")
    assert single["first_run"] == 1 and single["runs"] == 1

    _, batched_rows = read_metrics(tmp_path / "batched")
    _, single_rows = read_metrics(tmp_path / "single")
    run1 = [row for row in batched_rows if row["run"] == "1"]
    assert len(run1) == len(single_rows) == 10
    assert [row["run"] for row in single_rows] == ["1"] * 10  # labelled with the global index
    for mine, theirs in zip(single_rows, run1, strict=True):
        assert mine["update"] == theirs["update"]
        for key in ("return_mean", "grad_norm"):
            assert float(mine[key]) == pytest.approx(float(theirs[key]), rel=1e-5, abs=1e-5), (
                key, mine["update"])
        assert (mine["eval_return"] == "") == (theirs["eval_return"] == "")
        if mine["eval_return"]:
            assert float(mine["eval_return"]) == pytest.approx(float(theirs["eval_return"]),
                                                               rel=1e-5, abs=1e-5)
    for name, values in single["final_parameters"].items():
        assert values[0] == pytest.approx(batched["final_parameters"][name][1], rel=1e-5, abs=1e-5)
    # ... and the other runs of the batch really are different learners.
    run0 = [float(row["return_mean"]) for row in batched_rows if row["run"] == "0"]
    assert run0 != [float(row["return_mean"]) for row in run1]


def test_evaluation_does_not_shift_training(tmp_path):
    """Deterministic evaluation draws no exploration noise: eval_period leaves training alone."""
    curves = {}
    for period in (0, 3):
        build("runs=2", "updates=7", "episodes_per_update=5", f"eval_period={period}").train(
            tmp_path / str(period))
        _, rows = read_metrics(tmp_path / str(period))
        curves[period] = [(row["return_mean"], row["grad_norm"]) for row in rows]
        evaluated = {int(row["update"]) for row in rows if row["eval_return"]}
        assert evaluated == ({6} if period == 0 else {2, 5, 6})
    assert curves[0] == curves[3]


# --------------------------------------------------------------------------------------------
# 5. Group choices on the command line
# --------------------------------------------------------------------------------------------

@pytest.mark.e2e
@ON_ONE_WORKER
def test_group_choices_combine_with_experiment(jobs):
    result = jobs["rex_gauss_enac"].check()
    summaries = sweep_summaries(result)
    assert len(summaries) == 2
    by_explorer = {s["explorer"]: s for s in summaries}
    assert set(by_explorer) == {"rex", "sde_gauss"}
    for explorer, summary in by_explorer.items():
        assert summary["estimator"] == "enac", explorer
        assert summary["env"] == "minimize" and summary["actor"] == "linear"
        # The experiment's settings still apply on top of the chosen groups.
        assert summary["settings"]["eval_period"] == EVAL_PERIOD
        assert summary["runs"] == 1 and summary["settings"]["updates"] == 4
    # The choices took effect, not just their labels.
    assert "module.0.module.1.gaussian_param" in by_explorer["sde_gauss"]["final_parameters"]
    assert "module.0.module.1.gaussian_param" not in by_explorer["rex"]["final_parameters"]
    for job_dir in (d for d in result.out_dir.iterdir() if d.name.isdigit()):
        cfg = OmegaConf.load(job_dir / ".hydra" / "config.yaml")
        assert cfg.estimator._target_ == "sde_torchrl.objectives.estimators.ENACEstimator"
        assert cfg.explorer.schedule == ("step" if read_summary(job_dir)["explorer"] == "rex"
                                         else "episode")


@pytest.mark.e2e
@ON_ONE_WORKER
def test_every_n_choice_with_its_option(jobs):
    result = jobs["every_n"].check()
    summary = read_summary(result.out_dir)
    assert summary["explorer"] == "every_n" and summary["estimator"] == "reinforce"
    cfg = OmegaConf.load(result.out_dir / ".hydra" / "config.yaml")
    assert cfg.explorer.schedule == "every_n" and cfg.explorer.every_n == 3
    _, rows = read_metrics(result.out_dir)
    assert len(rows) == 4
    # logger=none: no TorchRL logger folder, but the job's own outputs are there.
    assert not (result.out_dir / "sde_torchrl").exists()
    assert (result.out_dir / "checkpoint.pt").is_file()


@pytest.mark.e2e
@ON_ONE_WORKER
def test_unknown_group_option_fails(jobs):
    result = jobs["nonsense"]
    assert result.returncode == 2  # a config error
    assert "nonsense" in result.stderr
    assert result.stderr.strip().splitlines()[-1].startswith("error: explorer=nonsense: expected one of ")
    assert "Traceback" not in result.stderr
    assert not (result.out_dir / "summary.json").exists()


@pytest.mark.e2e
def test_python_m_sde_torchrl_from_another_directory_runs_the_job_train_py_runs(tmp_path):
    """``python -m sde_torchrl`` (the installed command, ``sde-train``), started outside the clone,
    trains what ``train.py`` trains, byte for byte, with its ``train.log``; a second start on the
    finished job says so in one line and changes nothing."""
    job = ("+experiment=minimize", *TINY)
    script = subprocess.run([sys.executable, "train.py", *job, f"hydra.run.dir={tmp_path / 'script'}"], cwd=REPO,
                            capture_output=True, text=True, timeout=300)
    command = [sys.executable, "-m", "sde_torchrl", *job, f"hydra.run.dir={tmp_path / 'module'}"]
    module = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert script.returncode == 0 and module.returncode == 0, (script.stderr[-2000:], module.stderr[-2000:])
    assert (tmp_path / "module" / "metrics.csv").read_bytes() == (tmp_path / "script" / "metrics.csv").read_bytes()
    assert (tmp_path / "module" / "train.log").is_file()
    again = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and f"{tmp_path / 'module'} holds a finished job" in again.stdout, again


# --------------------------------------------------------------------------------------------
# 6. The exploration noise in collected episodes follows the explorer's schedule
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("explorer, extra", [("sde", ()), ("rex", ()),
                                             ("every_n", ("explorer.every_n=3",))])
def test_collected_noise_follows_schedule(explorer, extra):
    runs, episodes = 2, 3
    trainer = build(f"explorer={explorer}", *extra, f"runs={runs}",
                    f"episodes_per_update={episodes}")
    td = trainer.collect()
    noise = td["sde_noise"]
    assert noise.shape == (runs, episodes, EPISODE_LENGTH, 1, 1)
    changed = (noise[:, :, 1:] != noise[:, :, :-1]).flatten(3).any(-1)  # [runs, N, T-1]
    steps = torch.arange(1, EPISODE_LENGTH)
    if explorer == "sde":
        expected = torch.zeros(EPISODE_LENGTH - 1, dtype=torch.bool)  # constant in an episode
    elif explorer == "rex":
        expected = torch.ones(EPISODE_LENGTH - 1, dtype=torch.bool)  # new at every step
    else:
        expected = steps % 3 == 0  # redrawn at steps 3, 6, 9, 12
    assert torch.equal(changed, expected.expand_as(changed)), changed
    # Each episode (and each run) draws its own noise.
    first = noise[:, :, 0].flatten()
    assert len(set(first.tolist())) == runs * episodes

    # The recorded noise is what was applied: a = loc + expln(-2) ξ x (A = S = 1, no bias).
    sigma_hat = math.exp(-2.0)
    applied = td["loc"] + sigma_hat * noise[..., 0] * td["observation"]
    torch.testing.assert_close(td["action"], applied, rtol=1e-5, atol=1e-5)
