"""Where one whole training's time goes, ours and Stable-Baselines3's, from the process's start to its exit.

One cell of the gSDE table (:mod:`analysis.benchmarks.gsde_table`) is trained once per side, each in
a fresh process, from the one config :func:`~analysis.benchmarks.gsde_table.cells.compose_cell`
composes: ours as ``train.py`` runs it (:func:`sde_torchrl.cli.cli`), SB3's as the table runs it
(:func:`~analysis.benchmarks.gsde_table.run.run_sb3`, its settings read off that config). In that
process, and there only, the functions of each phase (:data:`OURS`, :data:`SB3`) are wrapped by one
timer whose phases are exclusive: each second goes to the innermost phase running; a module imported
later goes to ``late imports``, and ``torch.compile``'s own timer moves compilation out of the phase
that triggered it into ``compile warm-up``. Start-up runs from the parent's spawn to the timed
functions' modules imported, exit from the child's last timed line to the parent seeing it end, so
the rows add up to the process's wall time.
Writes the page ``<out>/<cell>.md`` and its record ``<record>/<cell>.json`` (the measured seconds).

Examples:
    python -m analysis.benchmarks.time_split --algorithm a2c --env hopper --fraction 0.01 --seed 0 \\
        --out docs/ppo/time_split
"""

from __future__ import annotations

import argparse
import functools
import importlib
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
#: The table's rows, in order; a side shows the phases it ran.
ROWS = ("start-up and imports", "late imports", "config composition", "env construction", "model construction",
        "compile warm-up", "collection", "normalisation", "advantage (GAE)", "update", "finite checks", "evaluation",
        "final check", "checkpoint", "metric files", "logging", "rest of the loop", "rest of the job", "exit")
#: Where time goes that no wrapped function holds (the child's own lines, the job's bookkeeping).
REST = "rest of the job"
#: Both sides: a module imported after start-up, wherever (``_find_and_load``: modules not yet loaded only).
IMPORTS = (("importlib._bootstrap", "_find_and_load", "late imports"),)
#: Ours: (module, attribute, phase) of ``train.py``'s job.
OURS = (
    ("sde_torchrl.cli.main", "cli", "config composition"),  # Hydra: composition, logging set-up
    ("sde_torchrl.cli.job", "validate", "config composition"),
    ("sde_torchrl.cli.job", "Job.__call__", REST),  # run directory held, .hydra/ written, run_job, Job.train
    ("sde_torchrl.config.build_onpolicy", "make_env", "env construction"),
    ("sde_torchrl.config.build_sac", "make_env", "env construction"),
    ("sde_torchrl.config.build_onpolicy", "build_onpolicy_trainer", "model construction"),
    ("sde_torchrl.config.build_sac", "build_sac_trainer", "model construction"),
    ("sde_torchrl.collectors.steps", "StepCollector.rollout", "collection"),
    ("sde_torchrl.trainers.offpolicy", "SACTrainer._collect_round", "collection"),  # and the replay buffer's extend
    ("sde_torchrl.envs.normalize", "RunningNormalize.observe", "normalisation"),
    ("sde_torchrl.envs.normalize", "RunningNormalize.normalize", "normalisation"),
    ("sde_torchrl.objectives.gae", "RolloutGAE.forward", "advantage (GAE)"),  # with the critic's values
    ("torchrl.objectives.value", "GAE.forward", "advantage (GAE)"),  # (TorchRL's, where RolloutGAE hands over)
    ("sde_torchrl.trainers.ppo", "PPOUpdate.__call__", "update"),
    ("sde_torchrl.trainers.a2c", "A2CUpdate.__call__", "update"),
    ("sde_torchrl.trainers.sac", "SACUpdate.__call__", "update"),
    ("torchrl.data", "ReplayBuffer.sample", "update"),
    ("sde_torchrl.trainers.step_job", "StepJob.check_return", "finite checks"),
    ("sde_torchrl.trainers.step_job", "StepJob.checked_statistics", "finite checks"),
    ("sde_torchrl.trainers.job", "Job.check_evaluation", "finite checks"),
    ("sde_torchrl.trainers.step_job", "StepJob.evaluate", "evaluation"),
    ("sde_torchrl.trainers.step_job", "StepJob.final_check", "final check"),
    ("sde_torchrl.trainers.job", "Job.save", "checkpoint"),
    ("sde_torchrl.jobs.run_dir", "MetricsFile.write", "metric files"),
    ("sde_torchrl.jobs.run_dir", "MetricsFile.sync", "metric files"),
    ("sde_torchrl.jobs.run_dir", "RunDirectory.write_summary", "metric files"),
    ("sde_torchrl.trainers.job", "write_best_policy", "metric files"),
    ("sde_torchrl.trainers.report", "Reporter.update", "logging"),  # the TorchRL logger's scalars, the log lines
    ("sde_torchrl.trainers.report", "Reporter.close", "logging"),
    ("sde_torchrl.trainers.job", "close_logger", "logging"),
    ("sde_torchrl.trainers.job", "Job.run_updates", "rest of the loop"),
    *IMPORTS,
)
#: SB3's: (module, attribute, phase) of the table's SB3 run.
SB3 = (
    ("analysis.benchmarks.gsde_table.sb3", "make_vec_env", "env construction"),
    ("stable_baselines3.common.vec_env", "VecNormalize.__init__", "env construction"),
    ("analysis.benchmarks.gsde_table.sb3", "build_model", "model construction"),
    ("stable_baselines3.common.on_policy_algorithm", "OnPolicyAlgorithm.collect_rollouts", "collection"),
    ("stable_baselines3.common.off_policy_algorithm", "OffPolicyAlgorithm.collect_rollouts", "collection"),
    ("stable_baselines3.common.vec_env", "VecNormalize.normalize_obs", "normalisation"),
    ("stable_baselines3.common.vec_env", "VecNormalize.normalize_reward", "normalisation"),
    ("stable_baselines3.common.vec_env", "VecNormalize._update_reward", "normalisation"),
    ("stable_baselines3.common.running_mean_std", "RunningMeanStd.update", "normalisation"),
    ("stable_baselines3.common.buffers", "RolloutBuffer.compute_returns_and_advantage", "advantage (GAE)"),
    ("stable_baselines3", "A2C.train", "update"),
    ("stable_baselines3", "PPO.train", "update"),
    ("stable_baselines3", "SAC.train", "update"),
    ("stable_baselines3.common.evaluation", "evaluate_policy", "evaluation"),
    ("stable_baselines3.common.vec_env", "sync_envs_normalization", "evaluation"),
    ("analysis.benchmarks.gsde_table.run", "write_run", "metric files"),  # the run's record
    ("stable_baselines3.common.base_class", "BaseAlgorithm._dump_logs", "logging"),
    ("stable_baselines3.common.on_policy_algorithm", "OnPolicyAlgorithm.learn", "rest of the loop"),
    ("stable_baselines3.common.off_policy_algorithm", "OffPolicyAlgorithm.learn", "rest of the loop"),
    *IMPORTS,
)


def compile_seconds() -> float:
    """Seconds ``torch.compile`` spent so far in this process, by torch's own timer (0 before dynamo is imported)."""
    spent = getattr(sys.modules.get("torch._dynamo.utils"), "calculate_time_spent", None)  # None while importing
    return spent()["total_wall_time"] if spent is not None else 0.0


def compiling() -> bool:
    """Whether ``torch.compile`` is compiling now (inside its own timer): no phase starts or ends
    within a compilation, so that its time is all in the span it is taken out of."""
    timer = getattr(sys.modules.get("torch._dynamo.utils"), "_dynamo_timed_tls", None)
    return getattr(timer, "depth", 0) > 0


class Split:
    """Seconds per phase, exclusive: a wrapped call's time goes to its phase less the wrapped calls inside it.

    Examples:
        >>> split = Split()
        >>> inner = split.wrap("inner", lambda: time.sleep(0.05))
        >>> split.wrap("outer", lambda: (time.sleep(0.01), inner()))()[1]
        >>> sorted(split.seconds), 0.01 <= split.seconds["outer"] < 0.05 <= split.seconds["inner"]
        (['inner', 'outer', 'rest of the job'], True)
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.stack = [REST]
        self.start()

    def start(self) -> float:
        """Start the clock (forgetting what was timed); returns the wall-clock time it started at."""
        self.seconds.clear()
        self.mark, self.compiled = time.perf_counter(), compile_seconds()
        return time.time()

    def switch(self) -> float:
        """Add the time since the last switch to the phase running (its compilation to ``compile
        warm-up``); returns the switch's clock."""
        now, compiled = time.perf_counter(), compile_seconds()
        compiling, self.compiled = compiled - self.compiled, compiled
        if compiling:
            self.seconds["compile warm-up"] = self.seconds.get("compile warm-up", 0.0) + compiling
        phase = self.stack[-1]
        self.seconds[phase] = self.seconds.get(phase, 0.0) + (now - self.mark) - compiling
        self.mark = now
        return now

    def wrap(self, phase: str, function):
        """``function``, its calls in the main thread timed under ``phase``."""
        main = threading.main_thread()

        @functools.wraps(function)
        def timed(*args, **kwargs):
            if threading.current_thread() is not main or compiling():
                return function(*args, **kwargs)
            self.switch()
            self.stack.append(phase)
            try:
                return function(*args, **kwargs)
            finally:
                self.switch()
                self.stack.pop()
        return timed

    def patch(self, table) -> None:
        """Wrap every ``(module, attribute, phase)`` of ``table`` where it is defined."""
        for module, attribute, phase in table:
            *path, name = attribute.split(".")
            owner = functools.reduce(getattr, path, importlib.import_module(module))
            setattr(owner, name, self.wrap(phase, getattr(owner, name)))


def child(side: str, spec_path: str, result_path: str) -> None:
    """One side's whole training in this (fresh) process, its phases timed into ``result_path``."""
    spec = json.loads(Path(spec_path).read_text())
    split = Split()
    split.patch(OURS if side == "ours" else SB3)  # start-up: importing the modules of the timed functions
    imports_done = split.start()
    if side == "ours":
        run_dir = Path(spec["out"]) / "ours"
        sys.argv = ["train.py", *spec["overrides"], f"hydra.run.dir={run_dir}"]
        code = sys.modules["sde_torchrl.cli.main"].cli()
        if code:
            raise SystemExit(f"train.py {' '.join(sys.argv[1:])} exited with {code}")
        env_steps = json.loads((run_dir / "summary.json").read_text())["env_steps"]
    else:
        from analysis.benchmarks.gsde_table.cells import Cell

        run = sys.modules["analysis.benchmarks.gsde_table.run"]
        cell = Cell(**spec["cell"])
        error = run.run_sb3(cell, spec["settings"], spec["fraction"], spec["overrides"], Path(spec["out"]))
        if error is not None:
            raise SystemExit(f"SB3's run failed: {error}")
        env_steps = json.loads(run.sb3_record(Path(spec["out"]), cell).read_text())["env_steps"]
    split.switch()
    end = time.time()
    Path(result_path).write_text(json.dumps({"imports_done": imports_done, "end": end, "phases": split.seconds,
                                             "env_steps": env_steps}))


def run_side(side: str, spec: dict, folder: Path) -> dict:
    """One side in a fresh process: ``{"phases", "wall_s", "env_steps"}``, start-up and exit included."""
    spec_path, result_path = folder / f"{side}_spec.json", folder / f"{side}_result.json"
    spec_path.write_text(json.dumps(spec))
    command = [sys.executable, "-m", "analysis.benchmarks.time_split", "child", side, str(spec_path), str(result_path)]
    start = time.time()
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True)
    end = time.time()
    if done.returncode:
        raise RuntimeError(f"the {side} process exited with {done.returncode}:\n{done.stderr[-3000:]}")
    result = json.loads(result_path.read_text())
    phases = {"start-up and imports": result["imports_done"] - start, **result["phases"], "exit": end - result["end"]}
    return {"phases": phases, "wall_s": end - start, "env_steps": result["env_steps"]}


def machine() -> dict:
    """Cores, CPU and the versions the runs ran on."""
    from analysis.benchmarks.common import versions

    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), "unknown CPU") if Path("/proc/cpuinfo").exists() else "unknown CPU"
    return {"cores": os.cpu_count(), "cpu": cpu, **versions("stable_baselines3")}


def markdown(record: dict) -> str:
    """The page: a lead saying what the table shows, then phase | ours s | SB3 s | ours ÷ SB3."""
    ours, sb3 = record["ours"]["phases"], record["sb3"]["phases"]
    walls = record["ours"]["wall_s"], record["sb3"]["wall_s"]
    gaps = sorted(((ours.get(p, 0.0) - sb3.get(p, 0.0), p) for p in ROWS), reverse=True)
    more = ", ".join(f"{p} (+{d:.1f} s)" for d, p in gaps[:3] if d > 0.05) or "none"
    less = ", ".join(f"{p} ({d:.1f} s)" for d, p in sorted(gaps)[:3] if d < -0.05) or "none"
    m = record["machine"]

    def cell(value):
        return "—" if value is None else f"{value:.2f}"

    lines = [f"# Where a whole training's time goes: {record['cell']}", "",
             f"One whole training of the gSDE table's cell `{record['cell']}` at {record['fraction']:g} of its "
             f"experiment's budget ({record['ours']['env_steps']} env steps ours, {record['sb3']['env_steps']} "
             f"SB3's), each side in a fresh process from its start to its exit: ours took {walls[0]:.1f} s, SB3's "
             f"{walls[1]:.1f} s ({walls[0] / walls[1]:.2f}× SB3's time). Ours spends more on {more}; less on "
             f"{less}. Ours is `train.py {' '.join(record['overrides'])}` as the table runs it; SB3's is the "
             "table's own SB3 run with the settings read off the same composed config. The phases are "
             "exclusive (normalisation is taken out of collection and evaluation, compilation out of the update, "
             "env construction out of model construction, a module imported after start-up out of wherever "
             "it is imported), so the rows add up to the process's wall time; "
             "`analysis/benchmarks/time_split.py` names the functions each phase times. Written by "
             f"`{record['command']}` on {record['date']} ({m['cores']} cores, {m['cpu']}; torch {m['torch']}, "
             f"Stable-Baselines3 {m['stable_baselines3']}), one process at a time.", "",
             "| phase | ours s | SB3 s | ours ÷ SB3 |", "| --- | --- | --- | --- |"]
    for phase in (p for p in ROWS if p in ours or p in sb3):
        a, b = ours.get(phase), sb3.get(phase)
        ratio = f"{a / b:.2f}" if a is not None and b else "—"
        lines.append(f"| {phase} | {cell(a)} | {cell(b)} | {ratio} |")
    lines.append(f"| whole process | {walls[0]:.2f} | {walls[1]:.2f} | {walls[0] / walls[1]:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """The command line; ``child`` is the timed process of one side."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["child"]:
        child(*argv[1:])
        return 0
    from analysis.benchmarks.gsde_table.cells import ALGORITHMS, ALL_ENVS, NOISES, Cell, compose_cell
    from analysis.benchmarks.gsde_table.sb3 import sb3_settings

    parser = argparse.ArgumentParser(prog="python -m analysis.benchmarks.time_split",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--algorithm", choices=ALGORITHMS, required=True)
    parser.add_argument("--env", choices=ALL_ENVS, required=True)
    parser.add_argument("--noise", choices=NOISES, default="sde")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fraction", type=float, required=True, help="fraction of the experiment's budget, in (0, 1]")
    parser.add_argument("--override", action="append", default=[], metavar="KEY=VALUE",
                        help="a train.py override, both sides (repeatable)")
    parser.add_argument("--out", type=Path, required=True, help="folder of the page, <cell>.md")
    parser.add_argument("--record", type=Path, default=Path("results/time_split"),
                        help="folder of the record, <cell>.json (default: results/time_split)")
    args = parser.parse_args(argv)
    cell = Cell(args.algorithm, args.env, args.noise, args.seed)
    try:  # one config, both sides
        conf, overrides = compose_cell(cell, args.fraction, args.override)
        spec = {"cell": vars(cell), "fraction": args.fraction, "overrides": list(overrides),
                "settings": sb3_settings(conf)}
    except ValueError as error:  # a bad value, or a setting SB3 cannot run
        parser.error(str(error))
    record = {"cell": cell.name, "fraction": args.fraction, "overrides": list(overrides),
              "command": " ".join(["python -m analysis.benchmarks.time_split", *argv]),
              "date": time.strftime("%Y-%m-%d"), "machine": machine()}
    with tempfile.TemporaryDirectory(prefix="time_split_") as tmp:
        for side in ("ours", "sb3"):  # one at a time
            record[side] = run_side(side, {**spec, "out": tmp}, Path(tmp))
    args.out.mkdir(parents=True, exist_ok=True)
    args.record.mkdir(parents=True, exist_ok=True)
    (args.record / f"{cell.name}.json").write_text(json.dumps(record, indent=1) + "\n")
    page = markdown(record)
    (args.out / f"{cell.name}.md").write_text(page)
    sys.stdout.write(page)
    return 0


if __name__ == "__main__":
    sys.exit(main())
