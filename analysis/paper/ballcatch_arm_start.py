"""Ball catching: what the arm does at the start of an episode, and what the authors' arm would do.

By the rule in ``docs/study/ballcatch/arm_start_rule.md``: the palm centre's height and pitch under zero
torque over the first second in the shipped arm (pybullet), and gravity's static torque about
each arm joint in the start pose from the figures of PyBrain's ``arm.xode`` (shapes, sizes and
densities), set against each joint's FMax of 0.5. Writes ``arm_start.json`` and ``arm_start.md``.

Usage:
    python -m analysis.paper.ballcatch_arm_start --out docs/study/ballcatch
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

GRAVITY = 9.81
FMAX = 0.5  # arm.xode: every arm joint's friction motor
TIMES = (0.0, 0.05, 0.1, 0.25, 0.5, 1.0)
#: x of the wrist axis forward of the shoulder's: the upper arm hangs straight down from the
#: shoulder (the elbow lies on the same vertical) and the forearm runs forward from x = 0 to 3.
WRIST_X = 3.0


def capsule_volume(radius: float, length: float) -> float:
    """A capsule's volume: a cylinder of ``length`` and two hemispherical caps.

    Examples:
        >>> round(capsule_volume(0.25, 3.0), 4)
        0.6545
    """
    return math.pi * radius**2 * length + 4 / 3 * math.pi * radius**3


def parts() -> list[tuple[str, float, float]]:
    """arm.xode's moving parts beyond the elbow: name, mass (density × volume) and the x of its
    centre of mass. The fingers' centres are taken at the middle of their 1.44-unit length from
    the palm's front edge (the thumb at the palm's centre line): a rough figure, a few percent
    of the torques."""
    finger = 5 * (capsule_volume(0.1, 0.75) + capsule_volume(0.1, 0.4) + capsule_volume(0.1, 0.29)
                  + 4 / 3 * math.pi * 0.1**3)
    return [
        ("forearm", 5 * capsule_volume(0.25, 3.0), 1.5),
        ("palm", 30 * 1.0 * 0.2 * 1.0, 3.5),
        *((f"finger {k}", finger, 4.0 + 0.72) for k in range(3)),
        ("thumb", finger, 3.5),
    ]


def weight_torques() -> dict[str, float]:
    """Gravity's torque about shoulder, elbow and wrist in the start pose, from :func:`parts`.

    Examples:
        >>> torques = weight_torques()
        >>> torques["shoulder"] == torques["elbow"] and torques["wrist"] < torques["elbow"]
        True
    """
    arm = parts()
    about = {"shoulder": 0.0, "elbow": 0.0, "wrist": WRIST_X}
    return {joint: sum(GRAVITY * mass * (x - axis) for _, mass, x in arm if x > axis)  # the parts beyond the joint
            for joint, axis in about.items()}


def measured_start() -> list[dict[str, float]]:
    """Palm centre height and pitch (rad) at :data:`TIMES` under zero torque in the shipped arm,
    the ball moved out of reach."""
    import pybullet

    from sde_torchrl.envs.ballcatch.world import TIME_STEP, BallCatchWorld

    world = BallCatchWorld()
    try:
        world.reset((0.0, 0.0))
        pybullet.resetBasePositionAndOrientation(world.ball, (20.0, 20.0, 5.0), (0, 0, 0, 1),
                                                 physicsClientId=world.client)
        rows, step = [], 0
        for time in TIMES:
            while step < round(time / TIME_STEP):
                world.step((0.0, 0.0, 0.0, 0.0))
                step += 1
            state = pybullet.getLinkState(world.robot, world.palm_link, computeForwardKinematics=1,
                                          physicsClientId=world.client)
            pitch = pybullet.getEulerFromQuaternion(state[1], physicsClientId=world.client)[1]
            rows.append({"time": time, "height": state[0][2], "pitch": pitch})
        return rows
    finally:
        world.close()


def decide(torques: dict[str, float]) -> str:
    """The rule's decision: ``"keep"`` if gravity's torque about any arm joint exceeds FMax.

    Examples:
        >>> decide({"shoulder": 0.3, "elbow": 0.2, "wrist": 0.1}), decide({"shoulder": 0.3, "elbow": 2.0, "wrist": 0.1})
        ('change', 'keep')
    """
    return "keep" if any(value > FMAX for value in torques.values()) else "change"


def markdown(numbers: dict) -> str:
    """The page ``arm_start.md``."""
    torques, rows = numbers["weight_torques"], numbers["measured"]
    verdict = ("**The shipped arm keeps its start**: by the authors' own figures gravity's torque about every "
               "arm joint is far above the joint's FMax, so ODE lets the arm sink as pybullet does."
               if numbers["decision"] == "keep" else
               "**The start changes**: by the authors' own figures ODE would hold the start pose.")
    lines = [
        "# Ball catching: the arm at the start of an episode",
        "",
        "Written by `analysis/paper/ballcatch_arm_start.py` (rule: `arm_start_rule.md`). "
        + verdict + " A policy has to lift and level the palm itself (the arm's maximum torques, 600 / 600 / 90, "
        "allow it); the arm held level is the diagnostic model `pybrain_held`.",
        "",
        "| joint | gravity's torque in the start pose (arm.xode's figures) | FMax | ratio |",
        "| --- | --- | --- | --- |",
        *(f"| {joint} | {value:.1f} | {FMAX} | {value / FMAX:.0f}× |" for joint, value in torques.items()),
        "",
        "The palm under zero torque in the shipped arm (the ball out of reach):",
        "",
        "| time (s) | palm centre height | palm pitch (rad) |",
        "| --- | --- | --- |",
        *(f"| {row['time']:g} | {row['height']:.3f} | {row['pitch']:.3f} |" for row in rows),
        "",
        "The parts counted: " + ", ".join(f"{name} {mass:.2f} at x = {x:g}" for name, mass, x in numbers["parts"])
        + " (mass, and the x of the centre of mass forward of the shoulder axis; the upper arm hangs straight "
        "down and adds nothing).",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    torques = weight_torques()
    numbers = {"fmax": FMAX, "parts": parts(), "weight_torques": torques, "decision": decide(torques),
               "measured": measured_start()}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "arm_start.json").write_text(json.dumps(numbers, indent=1) + "\n")
    (args.out / "arm_start.md").write_text(markdown(numbers))
    last = numbers["measured"][-1]
    print(f"the shipped arm {'keeps' if numbers['decision'] == 'keep' else 'changes'} its start: gravity's torques "
          + ", ".join(f"{joint} {value:.1f}" for joint, value in torques.items())
          + f" against FMax {FMAX}; the palm at {last['time']:g} s: height {last['height']:.3f}, pitch "
          f"{last['pitch']:.3f} rad; wrote {args.out / 'arm_start.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
