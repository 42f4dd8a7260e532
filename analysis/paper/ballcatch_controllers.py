"""Ball catching: what the final controllers of a sweep command, read from their parameters.

A run's final controller is ``u = tanh(Θ x)`` (4 commands: shoulder, elbow, wrist, fingers; the
ball's position as ``x``, or its scaled form with a constant feature). This reads ``Θ`` from each
job's ``summary.json`` (no simulation of the controllers) and evaluates the commands at two ball
positions: at the release, and where a caught ball rests in the hand of the shipped arm. Per sweep
and level of the final deterministic evaluation it reports the median finger command at the rest
positions and the share of runs whose command there closes an empty hand (:func:`closing_command`,
simulated once with constant commands), and the median shoulder and elbow commands at the release
(negative presses the arm down).

Writes ``controllers.json`` and ``controllers.md``.

Usage:
    python -m analysis.paper.ballcatch_controllers --out docs/study/ballcatch \
        "REINFORCE + SDE, Fig. 5=results/ballcatch/runs/fig5_seed3/sde" \
        "ENAC + SDE, Fig. 6=results/ballcatch/runs/fig6_seed3/sde"
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import torch

from analysis.figures import write_page_json
from analysis.sweeps import finished_jobs
from sde_torchrl.envs.ballcatch import BallCatchConfig, BallCatchWorld
from sde_torchrl.envs.ballcatch.models import ARM_MODELS, PYBRAIN_FINGERS
from sde_torchrl.envs.ballcatch.outcomes import LEVEL_NAMES, catch_level
from sde_torchrl.trainers.summary import mean_reward_factor

#: Ball positions the commands are read at: the release above the palm centre, and two rest
#: positions of a caught ball: above the palm centre, and rolled forward against the fingers of
#: the sunk, tilted palm (where catching REINFORCE + SDE controllers hold it).
POSITIONS = {"release": (3.5, 0.0, 5.5), "on the palm": (3.5, 0.0, 1.0), "against the fingers": (4.0, 0.0, 0.6)}
REST = ("on the palm", "against the fingers")
COMMANDS = ("shoulder", "elbow", "wrist", "fingers")
REPO = Path(__file__).resolve().parents[2]
#: The finger commands tried by :func:`closing_command`, and how long each is held.
COMMAND_GRID = tuple(round(0.05 * k, 2) for k in range(1, 21))
CLOSING_STEPS = 90
#: A finger has closed once its first hinge is past half its range (limits [0, 1.5]).
CLOSED_ANGLE = 0.75
#: Where the closing command is measured (the arm model, and the steps with zero torques before
#: the command starts): the shipped arm from the episode's start, its palm sinking while the hand
#: closes, as a catching hand meets it (the count's threshold); the palm held level; the shipped
#: arm once it has sunk and its fingers rest on the ground.
CLOSING_SITUATIONS = {"from the start": ("pybrain", 0), "level": ("pybrain_held", 0), "settled": ("pybrain", 150)}
#: Release height for these measurements: the ball is still far above when they end.
FAR_DROP_HEIGHT = 60.0


def closes(model: str, settle_steps: int, command: float) -> bool:
    """Whether a constant finger command (no arm torque), given after ``settle_steps`` steps with
    zero torques, closes every finger of an empty hand of ``model``: each first hinge past
    :data:`CLOSED_ANGLE` after :data:`CLOSING_STEPS` steps."""
    world = BallCatchWorld(BallCatchConfig(model=model, jitter=0.0, drop_height=FAR_DROP_HEIGHT))
    try:
        world.reset((0.0, 0.0))
        for _ in range(settle_steps):
            world.step((0.0, 0.0, 0.0, 0.0))
        for _ in range(CLOSING_STEPS):
            world.step((0.0, 0.0, 0.0, command))
        angles = world.joint_angles()
    finally:
        world.close()
    return min(angles[f"{finger}_0"] for finger in PYBRAIN_FINGERS) > CLOSED_ANGLE


def closing_command(model: str, settle_steps: int = 0) -> float:
    """The smallest command of :data:`COMMAND_GRID` from which every larger one closes the hand
    (:func:`closes`).

    Examples:
        >>> closing_command("pybrain_held")  # the palm held level
        0.25
    """
    closing = [closes(model, settle_steps, command) for command in COMMAND_GRID]
    if not closing[-1]:
        raise SystemExit(f"error: even the full finger command does not close the hand of model {model}")
    first_open = max((i for i, closed in enumerate(closing) if not closed), default=-1)
    return COMMAND_GRID[first_open + 1]


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
    for job in finished_jobs(sweep):
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


def group_numbers(runs: list[dict], closing: float) -> dict:
    """Median commands and the runs whose finger command at rest is at least ``closing``."""
    fingers = COMMANDS.index("fingers")
    numbers = {"runs": len(runs)}
    for rest in REST:
        command = [r["commands"][rest][fingers] for r in runs]
        numbers[rest] = {"median_fingers": statistics.median(command),
                         "closing": sum(c >= closing for c in command)}
    numbers["release"] = {name: statistics.median(r["commands"]["release"][i] for r in runs)
                          for i, name in enumerate(COMMANDS)}
    return numbers


def sweep_numbers(runs: list[dict], closing: float) -> dict:
    """:func:`group_numbers` per level of the final evaluation, best level first (levels no run
    reached are left out)."""
    return {level: group_numbers([r for r in runs if r["level"] == level], closing)
            for level in LEVEL_NAMES if any(r["level"] == level for r in runs)}


def markdown(numbers: dict) -> str:
    on_palm, against = (POSITIONS[name] for name in REST)
    closing = numbers["closing_command"]
    lines = [
        "# Ball catching: what the final controllers command",
        "",
        "Written by `analysis/paper/ballcatch_controllers.py` from the committed sweeps' final controllers "
        f"`u = tanh(Θ x)`, read from their parameters (the controllers are not simulated). A caught ball "
        f"rests {on_palm} above the palm centre, or {against}, rolled against the fingers of the sunk, tilted palm. "
        f"**Runs closing**: runs whose finger command there is at least {closing['from the start']:.2f}, the "
        "smallest constant command from which every larger one closes an empty hand of the shipped arm from the "
        f"episode's start, while its palm sinks (every finger's first hinge past half its range within "
        f"{CLOSING_STEPS / 100:g} s; simulated, in steps of 0.05). With the palm held level "
        f"{closing['level']:.2f} is enough; once the arm has sunk for {CLOSING_SITUATIONS['settled'][1] / 100:g} s "
        f"and its fingers rest on the ground, where they drag at friction 8, it takes {closing['settled']:.2f}. "
        "Release: the median commands with "
        f"the ball at {POSITIONS['release']} (shoulder and elbow below 0 press the arm down).",
        "",
        "| sweep | final level | runs | fingers on the palm: median, runs closing | against the fingers: median, "
        "runs closing | at release: shoulder, elbow, wrist, fingers |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for label, levels in numbers["sweeps"].items():
        for level, n in levels.items():
            rest = [f"{n[name]['median_fingers']:+.2f}, {n[name]['closing']} of {n['runs']}" for name in REST]
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
    closing = {name: closing_command(*situation) for name, situation in CLOSING_SITUATIONS.items()}
    numbers = {"closing_command": closing, "positions": POSITIONS, "paths": paths,
               "sweeps": {label: sweep_numbers(load(REPO / path), closing["from the start"])
                          for label, path in paths.items()}}
    args.out.mkdir(parents=True, exist_ok=True)
    write_page_json(args.out / "controllers.json", numbers)
    (args.out / "controllers.md").write_text(markdown(numbers))
    print(f"wrote {args.out / 'controllers.md'}")
    print(f"an empty hand closes from a finger command of {closing['from the start']:.2f} in the shipped arm "
          f"({closing['level']:.2f} with the palm level, {closing['settled']:.2f} once its fingers rest on the ground)")
    for label, levels in numbers["sweeps"].items():
        caught = [n for level, n in levels.items() if level in ("good catch", "catch")]
        runs, closing_runs = sum(n["runs"] for n in caught), sum(n[REST[1]]["closing"] for n in caught)
        print(f"{label}: the finger command closes the hand on a resting ball in {closing_runs} of the {runs} runs "
              "ending with a catch")
    return 0


if __name__ == "__main__":
    sys.exit(main())
