"""Ball catching: what the final controllers of a sweep command, read from their parameters.

A run's final controller is ``u = tanh(Θ x)`` (4 commands: shoulder, elbow, wrist, fingers; the
ball's position as ``x``, or its scaled form with a constant feature). This reads ``Θ`` from each
job's ``summary.json`` (no simulation) and evaluates the commands at two ball positions: at the
release, and where a caught ball rests in the hand of the shipped arm. Per sweep and level of the
final deterministic evaluation it reports the median finger command at the rest positions and the
share of runs whose command there exceeds the fraction of the finger actuator's torque that lifts
a straight finger off the palm (below it the hand does not close, whatever the command), and the
median shoulder and elbow commands at the release (negative presses the arm down).

Writes ``controllers.json`` and ``controllers.md``.

Usage:
    python -m analysis.paper.ballcatch_controllers --out docs/ballcatch \
        "REINFORCE + SDE, Fig. 5=results/ballcatch/runs/fig5_seed3/sde" \
        "ENAC + SDE, Fig. 6=results/ballcatch/runs/fig6_seed3/sde"
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import torch

from sde_torchrl.envs.ballcatch.models import ARM_MODELS, PYBRAIN_MAX_TORQUES
from sde_torchrl.envs.ballcatch.outcomes import LEVEL_NAMES, catch_level
from sde_torchrl.jobs.run_dir import finished_runs
from sde_torchrl.trainers.summary import mean_reward_factor

#: Torque that lifts a straight finger off the palm at its first hinge: gravity's 2.42 and the
#: joint friction 0.5 (the figures behind ``PYBRAIN_MAX_TORQUES``' finger torque).
FINGER_LIFT_TORQUE = 2.42 + 0.5
LIFT_SHARE = FINGER_LIFT_TORQUE / PYBRAIN_MAX_TORQUES[3]
#: Ball positions the commands are read at: the release above the palm centre, and two rest
#: positions of a caught ball: above the palm centre, and rolled forward against the fingers of
#: the sunk, tilted palm (where catching REINFORCE + SDE controllers hold it).
POSITIONS = {"release": (3.5, 0.0, 5.5), "on the palm": (3.5, 0.0, 1.0), "against the fingers": (4.0, 0.0, 0.6)}
REST = ("on the palm", "against the fingers")
COMMANDS = ("shoulder", "elbow", "wrist", "fingers")
REPO = Path(__file__).resolve().parents[2]


def features(position: tuple[float, float, float], observation: str) -> torch.Tensor:
    """The controller's input for a ball at ``position``: the position (``raw``), or mapped onto
    ``[-1, 1]`` over the shipped arm's workspace with a constant 1 appended (``scaled``).

    Examples:
        >>> features((3.5, 0.0, 5.5), "scaled").tolist()
        [0.0, 0.0, 0.8333333333333334, 1.0]
    """
    ball = torch.tensor(position, dtype=torch.float64)
    if observation == "raw":
        return ball
    low, high = torch.tensor(ARM_MODELS["pybrain"].workspace, dtype=torch.float64).unbind(-1)
    return torch.cat([(ball - (low + high) / 2) / ((high - low) / 2), torch.ones(1, dtype=torch.float64)])


def load(sweep: Path) -> list[dict]:
    """Every run of the sweep's jobs: its final evaluation (mean reward per step), its level and
    its commands at :data:`POSITIONS`."""
    runs = []
    for job in finished_runs(sweep):
        summary = job.summary
        if summary["env"] != "ballcatch" or summary["actor"] != "linear":
            raise SystemExit(f"error: {job.path} is not a linear ball-catching job")
        weights = [v for k, v in summary["final_parameters"].items() if k.endswith("module.weight")]
        if len(weights) != 1:
            raise SystemExit(f"error: {job.path}: expected one controller weight in final_parameters")
        observation = summary["config"]["env"]["observation"]
        theta = torch.tensor(weights[0], dtype=torch.float64)
        theta = theta.reshape(theta.shape[0], len(COMMANDS), -1)
        factor = mean_reward_factor(summary)
        for index, final in enumerate(summary["final_eval_return"]):
            commands = {name: torch.tanh(theta[index] @ features(position, observation)).tolist()
                        for name, position in POSITIONS.items()}
            runs.append({"final": factor * final, "level": catch_level(factor * final), "commands": commands})
    if not runs:
        raise SystemExit(f"error: no finished job under {sweep}")
    return runs


def group_numbers(runs: list[dict]) -> dict:
    """Median commands and the share of runs whose finger command at rest lifts a finger."""
    fingers = COMMANDS.index("fingers")
    numbers = {"runs": len(runs)}
    for rest in REST:
        command = [r["commands"][rest][fingers] for r in runs]
        numbers[rest] = {"median_fingers": statistics.median(command),
                         "lifting": sum(c > LIFT_SHARE for c in command)}
    numbers["release"] = {name: statistics.median(r["commands"]["release"][i] for r in runs)
                          for i, name in enumerate(COMMANDS)}
    return numbers


def sweep_numbers(runs: list[dict]) -> dict:
    """:func:`group_numbers` per level of the final evaluation, best level first (levels no run
    reached are left out)."""
    return {level: group_numbers([r for r in runs if r["level"] == level])
            for level in LEVEL_NAMES if any(r["level"] == level for r in runs)}


def markdown(numbers: dict) -> str:
    on_palm, against = (POSITIONS[name] for name in REST)
    lines = [
        "# Ball catching: what the final controllers command",
        "",
        "Written by `analysis/paper/ballcatch_controllers.py` from the committed sweeps' final controllers "
        f"`u = tanh(Θ x)`, read from their parameters (no simulation). A caught ball rests {on_palm} "
        f"above the palm centre, or {against}, rolled against the fingers of the sunk, tilted palm. "
        f"**Fingers lift**: runs whose finger command there exceeds {LIFT_SHARE:.2f}, the share of the finger "
        f"actuator's torque ({PYBRAIN_MAX_TORQUES[3]:g}) that lifts a straight finger off the palm "
        f"({FINGER_LIFT_TORQUE:.2f}); below it the hand does not close. Release: the median commands with "
        f"the ball at {POSITIONS['release']} (shoulder and elbow below 0 press the arm down).",
        "",
        "| sweep | final level | runs | fingers on the palm: median, runs lifting | against the fingers: median, "
        "runs lifting | at release: shoulder, elbow, wrist, fingers |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for label, levels in numbers["sweeps"].items():
        for level, n in levels.items():
            rest = [f"{n[name]['median_fingers']:+.2f}, {n[name]['lifting']} of {n['runs']}" for name in REST]
            release = ", ".join(f"{n['release'][c]:+.2f}" for c in COMMANDS)
            lines.append(f"| {label} | {level} | {n['runs']} | {rest[0]} | {rest[1]} | {release} |")
    lines += ["", "Sweeps: " + "; ".join(f"{label}: `{path}`" for label, path in numbers["paths"].items()) + ".", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__.splitlines()[0])
    parser.add_argument("sweeps", nargs="+", help="LABEL=DIRECTORY, a sweep's jobs under DIRECTORY")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    paths = {}
    for item in args.sweeps:
        label, sep, path = item.partition("=")
        if not sep or not label or not path:
            parser.error(f"{item!r}: give each sweep as LABEL=DIRECTORY")
        resolved = Path(path).resolve()
        paths[label] = str(resolved.relative_to(REPO)) if resolved.is_relative_to(REPO) else path
    numbers = {"lift_share": LIFT_SHARE, "positions": POSITIONS, "paths": paths,
               "sweeps": {label: sweep_numbers(load(REPO / path)) for label, path in paths.items()}}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "controllers.json").write_text(json.dumps(numbers, indent=1) + "\n")
    (args.out / "controllers.md").write_text(markdown(numbers))
    for label, levels in numbers["sweeps"].items():
        caught = [n for level, n in levels.items() if level in ("good catch", "catch")]
        runs, lifting = sum(n["runs"] for n in caught), sum(n[REST[1]]["lifting"] for n in caught)
        print(f"{label}: the hand closes on a resting ball in {lifting} of the {runs} runs ending with a catch")
    print(f"wrote {args.out / 'controllers.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
