"""Sweeps on distributed engines: Ray (hydra-ray-launcher, a local cluster started on loopback)
and Slurm's launcher (hydra-submitit-launcher, with submitit's local executor).

They need the launchers that ``pip install -e ".[dev]"`` installs (``ray``, ``sweeps`` extras) and
are skipped without them (``tests/conftest.py``). Each trains a sweep split into shards through
the launcher and checks that the merged shards equal one process.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from test_sweeps import _metrics, _train

pytestmark = pytest.mark.launchers
REPO = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _shards_equal_one_process(tmp_path: Path, *launcher: str) -> None:
    _train("runs=4", f"hydra.run.dir={tmp_path / 'one'}")
    _train("runs=2", "first_run=0,2", *launcher, f"hydra.sweep.dir={tmp_path / 'shards'}", multirun=True)
    one, shards = _metrics(tmp_path / "one"), _metrics(tmp_path / "shards")
    assert len(one) == 4 * 6 and len(list((tmp_path / "shards").rglob("summary.json"))) == 2
    assert shards == one


@pytest.mark.e2e
def test_submitit_local_executor_shards_equal_one_process(tmp_path):
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    _shards_equal_one_process(tmp_path, "hydra/launcher=submitit_local", "hydra.launcher.timeout_min=10")


def test_slurm_config_composes_for_submitit(tmp_path):
    """The shipped Slurm config is a submitit_slurm launcher with our per-shard resources: here
    for a ball-catching shard of 50 runs (one shard of the study's Fig. 5 sweep)."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    result = subprocess.run(
        [sys.executable, "train.py", "+experiment=ballcatch_paper", "runs=50", "hydra/launcher=slurm", "--cfg",
         "all", "--resolve"], cwd=REPO, capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "SlurmLauncher" in result.stdout and "cpus_per_task: 1" in result.stdout
    assert "mem_gb: 9" in result.stdout and "timeout_min: 162" in result.stdout


#: The library's experiments (conf/experiment/; the study's sweeps: tests/study/test_study_launchers.py),
#: and a ball-catching shard of 50 runs (as the study's Fig. 5 sweep splits its jobs).
JOBS = [(f"+experiment={p.stem}",) for p in sorted((REPO / "conf" / "experiment").glob("*.yaml"))]
JOBS.append(("+experiment=ballcatch_paper", "runs=50"))


def requests_cover_the_estimates(overrides: list[str], launcher: str) -> None:
    """The job of ``overrides`` composed with the cluster ``launcher`` asks, per shard, for at least
    the memory and the time that shard is estimated to need (sde_torchrl/jobs/resources.py)."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher" if launcher == "slurm"
                        else "hydra_plugins.hydra_ray_launcher")
    from omegaconf import OmegaConf

    from sde_torchrl.config.compose import compose
    from sde_torchrl.config.schemas.train import validate
    from sde_torchrl.jobs.resources import GB, estimate_memory, estimate_minutes

    overrides = [*overrides, f"hydra/launcher={launcher}", "max_memory_gb=1000"]
    request = OmegaConf.to_container(compose(overrides, return_hydra_config=True).hydra.launcher, resolve=True)
    job = validate(compose(overrides))
    if launcher == "slurm":
        assert request["mem_gb"] >= estimate_memory(job).total / GB and request["mem_gb"] >= 1
        assert request["timeout_min"] >= estimate_minutes(job)
    else:
        assert request["ray"]["remote"]["memory"] >= estimate_memory(job).total


@pytest.mark.parametrize("launcher", ["slurm", "ray_cluster"])
@pytest.mark.parametrize("job", JOBS, ids=" ".join)
def test_every_experiment_requests_what_its_shards_are_estimated_to_use(job, launcher):
    """Each experiment composed with each cluster launcher asks, per shard, for at least the
    memory and the time that shard is estimated to need."""
    requests_cover_the_estimates(list(job), launcher)


@pytest.fixture()
def ray_head():
    """A Ray head node on 127.0.0.1 (2 CPUs, no dashboard), stopped afterwards. Its temp dir is
    short: Ray's Unix socket paths must fit in 107 characters."""
    pytest.importorskip("hydra_plugins.hydra_ray_launcher")
    ray = shutil.which("ray", path=str(Path(sys.executable).parent)) or shutil.which("ray")
    if ray is None:
        pytest.skip("the ray command is not installed")
    port = _free_port()
    start = [ray, "start", "--head", "--node-ip-address=127.0.0.1", f"--port={port}", "--num-cpus=2",
             "--include-dashboard=false", "--disable-usage-stats"]
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")
    start.append(f"--temp-dir={temp}")
    started = subprocess.run(start, capture_output=True, text=True, timeout=180)
    assert started.returncode == 0, started.stderr[-2000:]
    try:
        yield f"127.0.0.1:{port}"
    finally:
        subprocess.run([ray, "stop", "--force"], capture_output=True, timeout=120)
        shutil.rmtree(temp, ignore_errors=True)


@pytest.mark.e2e
def test_ray_cluster_shards_equal_one_process(tmp_path, ray_head):
    _shards_equal_one_process(tmp_path, "hydra/launcher=ray_cluster", f"hydra.launcher.ray.init.address={ray_head}")


def _descendants(pid: int) -> list[int]:
    """The processes below ``pid`` (children, their children, ...), from each process's parent in ``/proc``."""
    parents = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parents[int(stat.parent.name)] = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):  # ended meanwhile
            continue
    found, todo = [], [pid]
    while todo:
        below = todo.pop()
        children = [child for child, parent in parents.items() if parent == below]
        found += children
        todo += children
    return found


def _command_line(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:  # ended meanwhile
        return b""


@pytest.mark.e2e
def test_submitit_preemption_checkpoints_requeues_and_resumes(tmp_path):
    """submitit's preemption / time-limit signal (SIGUSR2, as ``job._interrupt()`` sends it):
    the job checkpoints after its update, submitit requeues it, and the requeued job resumes to
    the outputs of an uninterrupted run, although it checkpoints nowhere else (checkpoint_period=0)."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    job = ("+experiment=minimize", "runs=2", "updates=300", "eval_period=10", "checkpoint_period=0", "logger=none")
    reference = subprocess.Popen([sys.executable, "train.py", *job, f"hydra.run.dir={tmp_path / 'one'}"],
                                 cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    sweep = tmp_path / "shards"
    launched = subprocess.Popen(
        [sys.executable, "train.py", "-m", *job, "hydra/launcher=submitit_local", "hydra.launcher.timeout_min=10",
         f"hydra.sweep.dir={sweep}"], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    metrics, deadline = sweep / "0" / "metrics.csv", time.monotonic() + 180
    while not metrics.exists() or len(metrics.read_bytes().splitlines()) < 60:
        assert launched.poll() is None, launched.communicate()[1][-2000:]
        assert time.monotonic() < deadline, "no progress"
        time.sleep(0.02)
    tasks = [pid for pid in _descendants(launched.pid) if b"submitit.core._submit" in _command_line(pid)]
    assert len(tasks) == 1, tasks
    os.kill(tasks[0], signal.SIGUSR2)
    _, stderr = launched.communicate(timeout=300)
    assert launched.returncode == 0, stderr[-2000:]
    assert reference.wait(timeout=300) == 0, reference.stderr.read()[-2000:]
    log = (sweep / "0" / "train.log").read_text()
    assert "SIGUSR2: checkpoint after update" in log and "resuming" in log, log[-2000:]
    assert metrics.read_bytes() == (tmp_path / "one" / "metrics.csv").read_bytes()
