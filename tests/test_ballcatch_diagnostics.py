"""The ball-catching diagnostics' pages: the arm's start (measured, and gravity's torques from
the authors' figures) and the final policies re-evaluated with the arm held level; each page
equals what its script writes from the committed numbers."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from _helpers import load_script

arm_start = load_script("ballcatch_arm_start")
DOCS = Path(__file__).parents[1] / "docs" / "ballcatch"


def test_the_arm_start_page_is_its_scripts_output_and_the_measurement_holds():
    numbers = json.loads((DOCS / "arm_start.json").read_text())
    assert (DOCS / "arm_start.md").read_text() == arm_start.markdown(numbers)
    assert numbers["weight_torques"] == pytest.approx(arm_start.weight_torques())
    assert numbers["decision"] == arm_start.decide(numbers["weight_torques"]) == "keep"
    assert [row["height"] for row in numbers["measured"]] == pytest.approx(
        [row["height"] for row in arm_start.measured_start()], abs=1e-6)


def test_gravity_torques_agree_with_the_simulators_inverse_dynamics():
    """The hand count from arm.xode's figures against pybullet's inverse dynamics of the ported
    arm in the start pose (307.8 about shoulder and elbow, 46.6 about the wrist)."""
    import pybullet

    from sde_torchrl.envs.ballcatch.world import BallCatchWorld

    world = BallCatchWorld()
    try:
        joints = pybullet.getNumJoints(world.robot, physicsClientId=world.client)
        movable = [j for j in range(joints)
                   if pybullet.getJointInfo(world.robot, j, physicsClientId=world.client)[2] != pybullet.JOINT_FIXED]
        zeros = [0.0] * len(movable)
        torques = pybullet.calculateInverseDynamics(world.robot, zeros, zeros, zeros, physicsClientId=world.client)
    finally:
        world.close()
    by_hand = arm_start.weight_torques()
    for joint, simulated in zip(("shoulder", "elbow", "wrist"), torques[:3], strict=True):
        assert abs(simulated) == pytest.approx(by_hand[joint], rel=0.02), joint
