"""Tests of the ball-catching episode outcomes (levels and behaviours) and of the diagnostic arm
``pybrain_held``, against the simulator's own contact queries."""

from __future__ import annotations

import math

import numpy as np
import pybullet
import pytest
import torch

from sde_torchrl.envs.ballcatch import BallCatchConfig, BallCatchWorld, CatchEpisode, scripted_weights
from sde_torchrl.envs.ballcatch.outcomes import BEHAVIOURS, LEVELS, catch_level, catch_outcomes

PULL_BACK = np.array([[-2.0, 0, 0], [-2.0, 0, 0], [-2.0, 0, 0], [0, 0, 0]])
OPEN_HAND = np.array([[0.0, 0, 0], [0, 0, 0], [0, 0, 0], [-1.0, 0, 0]])


def simulated(model: str, weights: np.ndarray, offset=(0.02, -0.01)) -> dict:
    """One episode of ``tanh(W x)``: the ball's path, finger actions, rewards, the step of the
    first contact that the simulator reports between ball and hand, and the palm's last pose."""
    world = BallCatchWorld(BallCatchConfig(model=model))
    episode = CatchEpisode(world)
    episode.reset(offset)
    ball, finger, reward, touch = [episode.ball], [], [], 0
    for step in range(1, 501):
        action = np.tanh(weights @ np.asarray(episode.ball))
        finger.append(action[3])
        reward.append(episode.step(action))
        ball.append(episode.ball)
        if not touch and not episode.grounded and world.ball_touches_hand():
            touch = step
    state = pybullet.getLinkState(world.robot, world.palm_link, physicsClientId=world.client)
    pitch = pybullet.getEulerFromQuaternion(state[1], physicsClientId=world.client)[1]
    world.close()
    outcome = catch_outcomes(torch.tensor([ball]), torch.tensor([finger]), torch.tensor([reward]),
                             world.config.arm.ground_z)
    return {"outcome": {k: v.item() for k, v in outcome.items()}, "touch": touch, "return": np.mean(reward),
            "palm": state[0], "pitch": pitch}


@pytest.mark.parametrize(("model", "weights", "behaviour"), [
    ("pybrain", "scripted", "held"),
    ("pybrain", OPEN_HAND, "dropped"),
    ("pybrain_held", "scripted", "held"),
    ("pybrain_held", OPEN_HAND, "kept on the hand"),
    ("cup", "scripted", "held"),
])
def test_first_contact_and_behaviour_agree_with_the_simulator(model, weights, behaviour):
    weights = scripted_weights(model) if isinstance(weights, str) else weights
    episode = simulated(model, weights)
    outcome = episode["outcome"]
    assert BEHAVIOURS[outcome["behaviour"]] == behaviour
    assert outcome["first_contact"] == episode["touch"] > 0  # the step pybullet's contact query names
    if behaviour == "dropped":
        assert outcome["dropped"] and math.isnan(outcome["hold_distance"])
    else:
        assert 0.5 <= outcome["hold_distance"] < 1.0


def test_a_ball_that_touches_nothing_before_the_ground_has_no_first_contact():
    episode = simulated("cup", np.zeros((4, 3)))  # the cup arm falls away under zero torque
    assert episode["touch"] == 0
    assert episode["outcome"]["first_contact"] == 0 and episode["outcome"]["dropped"]


def test_hold_distance_is_the_mean_distance_from_the_first_contact_on():
    ball = torch.tensor([[[0.0, 0, 5.0], [0, 0, 4.0], [0, 0, 3.0], [0, 0, 3.0], [0, 0, 3.0]]])  # stopped in step 3
    reward = torch.tensor([[-3.0, -2.0, -0.7, -0.9]])
    out = catch_outcomes(ball, torch.ones(1, 4), reward, ground_z=0.41)
    assert out["first_contact"].item() == 3
    assert out["hold_distance"].item() == pytest.approx((0.7 + 0.9) / 2)


def test_levels_are_the_papers():
    assert [bound for bound, _ in LEVELS] == [-1.0, -1.1, -1.5, -2.0]
    assert catch_level(-1.0) == "good catch" and catch_level(-1.1000001) == "on the hand"
    assert catch_level(-2.0) == "slowed" and catch_level(-2.0001) == "dropped"


def test_the_held_arm_keeps_the_palm_level_where_the_shipped_arm_sinks():
    held, shipped = simulated("pybrain_held", PULL_BACK), simulated("pybrain", OPEN_HAND)
    assert held["palm"][2] == pytest.approx(0.5, abs=0.01) and abs(held["pitch"]) < 0.01  # pulling back does nothing
    assert shipped["palm"][2] < 0.3 and abs(shipped["pitch"]) > 0.1
    assert BallCatchConfig(model="pybrain_held").max_torques == BallCatchConfig().max_torques
