"""The ball-catching arms: what differs between them (:class:`ArmModel`, :data:`ARM_MODELS`) and
each one's hand-written catching controller (:func:`scripted_weights`).

Four models share the task rules (:mod:`~sde_torchrl.envs.ballcatch.task`): ``"pybrain"`` (the
default, after the arm of the paper's authors' library), ``"cup"`` (a three-joint arm with a
four-finger cupped hand) and two diagnostics built on ``"pybrain"``, ``"pybrain_held"`` and
``"pybrain_strong_fingers"``; :data:`ARM_MODELS` describes each. Plain data (no pybullet): the
physics that reads it is :mod:`~sde_torchrl.envs.ballcatch.world`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

__all__ = [
    "ARM_MODELS",
    "DEFAULT_MODEL",
    "DISTAL_TORQUE_RATIO",
    "JOINT_TRANSMISSION",
    "MAX_TORQUES",
    "PYBRAIN_MAX_TORQUES",
    "PYBRAIN_SCRIPTED_WEIGHTS",
    "SCRIPTED_WEIGHTS",
    "STRONG_FINGER_TORQUES",
    "ArmModel",
    "scripted_action",
    "scripted_weights",
]

BALL_RADIUS = 0.45
BALL_MASS = 0.5
DROP_HEIGHT = 5.0
MAX_TORQUES = (150.0, 80.0, 30.0, 5.0)
"""Maximum torque (N m) of shoulder, elbow, wrist and the finger actuator (model "cup"; see
:meth:`~sde_torchrl.envs.ballcatch.world.BallCatchWorld.joint_forces`)."""

DISTAL_TORQUE_RATIO = 0.4
"""Distal finger joints get this fraction of the finger torque (one actuator, fixed transmission)."""

ARM_JOINTS = ("shoulder", "elbow", "wrist")
FINGER_NAMES = ("front", "left", "back", "right")
JOINT_TRANSMISSION = ((0, 1.0), (1, 1.0), (2, 1.0)) + ((3, 1.0), (3, DISTAL_TORQUE_RATIO)) * len(FINGER_NAMES)
"""For each of the 11 joints (arm, then proximal and distal joint of every finger): the actuator
driving it and the fraction of that actuator's torque it gets."""
INITIAL_ARM_POSE = (0.0, 0.0, -0.15)
"""Catching pose = upper limits of shoulder, elbow and wrist (palm tilted 0.15 rad outwards)."""
INITIAL_FINGER_POSE = (0.0, 0.9)
"""Open hand (proximal, distal): the lower finger limits. The distal links stay bent up by at
least 0.9 rad, a lip that keeps a ball on the open hand's outer finger."""

PYBRAIN_FINGERS = ("thumb", "index", "middle", "ring")
PYBRAIN_BALL_RADIUS = 0.4
PYBRAIN_MAX_TORQUES = (600.0, 600.0, 90.0, 5.0)
"""Maximum torques of model "pybrain" (shoulder, elbow, wrist, every finger joint): 1.5 times
the static torques that hold the arm in its start pose with the ball resting on the palm
(shoulder and elbow 307.8 + 92.0, wrist 46.6 + 13.2, from pybullet's inverse dynamics and the
ball's weight) and, for the fingers, 1.5 times what lifts a straight finger off the palm (gravity
2.42 plus joint friction 0.5 at the first hinge), rounded up: 600, 600, 90 and 5. A
saturated controller can then lift the loaded arm and close the hand against gravity and friction.
On a level palm a smaller command closes the hand too: the distal hinges, which carry less, curl
first, and the folded finger's weight then acts closer to its first hinge."""

STRONG_FINGER_TORQUES = PYBRAIN_MAX_TORQUES[:3] + (2.0 * PYBRAIN_MAX_TORQUES[3],)
"""Maximum torques of the diagnostic model "pybrain_strong_fingers": those of model "pybrain" with
the finger actuator doubled (10)."""


@dataclass(frozen=True)
class ArmModel:
    """Everything that differs between the ball-catching arms (:data:`ARM_MODELS`).

    Args:
        urdf: robot description, a file in ``sde_torchrl/envs/assets``.
        joints: names of the actuated joints, in the order of ``transmission``.
        transmission: for each joint, the actuator (0 shoulder, 1 elbow, 2 wrist, 3 fingers)
            driving it and the fraction of that actuator's torque it gets.
        joint_friction: maximum force of each joint's velocity motor with target 0 (ODE's FMax
            joint friction); 0 switches the motor off (pure torque control).
        initial_pose: joint angles at the start of every episode.
        ball_radius: radius of the ball.
        ball_mass: default mass of the ball (:attr:`~sde_torchrl.envs.ballcatch.world.BallCatchConfig.ball_mass`).
        drop_height: default release height above the palm centre.
        max_torques: default maximum torques (shoulder, elbow, wrist, fingers).
        friction: default lateral friction of every body (ball, robot, ground); pybullet
            multiplies the two bodies' values in a contact.
        restitution: restitution of the robot and the ground (the ball's is ``ball_restitution``);
            pybullet multiplies the two bodies' values too.
        ball_restitution: restitution of the ball.
        joint_damping: default viscous damping of every joint.
        body_damping: linear and angular damping of the ball and every link, or ``None`` for
            pybullet's default (0.04, a drag of ``m v (0.04 + 0.04 |v|)`` that ODE does not have).
        solver_iterations: default pybullet ``numSolverIterations``.
        inertia_from_file: use the URDF's inertia tensors (pybullet otherwise derives them from
            the collision shapes' bounding boxes).
        camera_target: where the rendering camera looks.
        camera_yaw: the camera's yaw in degrees (it looks from 8 units away, 12 degrees down).
        workspace: the box ``(low, high)`` per coordinate (x, y, z) where the ball is while an
            episode is live (around the palm, from the ground to above the release), which the
            scaled observation maps onto ``[-1, 1]``.
        hold_arm: hold shoulder, elbow and wrist at ``initial_pose`` (position control far
            stronger than any torque) and ignore the action's arm torques.

    Examples:
        >>> round(ARM_MODELS["pybrain"].ground_z, 6), len(ARM_MODELS["pybrain"].joints)
        (0.41, 15)
    """

    urdf: str
    joints: tuple[str, ...]
    transmission: tuple[tuple[int, float], ...]
    joint_friction: tuple[float, ...]
    initial_pose: tuple[float, ...]
    ball_radius: float
    ball_mass: float
    drop_height: float
    max_torques: tuple[float, float, float, float]
    friction: float
    restitution: float
    ball_restitution: float
    joint_damping: float
    body_damping: float | None
    solver_iterations: int
    inertia_from_file: bool
    camera_target: tuple[float, float, float]
    camera_yaw: float
    workspace: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    hold_arm: bool = False

    @property
    def ground_z(self) -> float:
        """The ball counts as having touched the ground once its centre is below this height."""
        return self.ball_radius + 0.01


DEFAULT_MODEL = "pybrain"
"""The arm of ``BallCatch-v0``, ``env=ballcatch`` and the paper experiments: the authors' arm."""

_PORTED_ARMS = {
    "pybrain": ArmModel(
        urdf="arm_pybrain.urdf",
        joints=ARM_JOINTS + tuple(f"{f}_{k}" for f in PYBRAIN_FINGERS for k in range(3)),
        transmission=((0, 1.0), (1, 1.0), (2, 1.0)) + ((3, 1.0),) * (3 * len(PYBRAIN_FINGERS)),
        joint_friction=(0.5, 0.5, 0.5) + (0.5, 0.25, 0.1) * len(PYBRAIN_FINGERS),
        initial_pose=(0.0,) * (3 + 3 * len(PYBRAIN_FINGERS)),
        ball_radius=PYBRAIN_BALL_RADIUS,
        ball_mass=10.0 * 4.0 / 3.0 * math.pi * PYBRAIN_BALL_RADIUS**3,  # density 10
        drop_height=DROP_HEIGHT,
        max_torques=PYBRAIN_MAX_TORQUES,
        friction=math.sqrt(8.0),
        restitution=math.sqrt(0.2),
        ball_restitution=math.sqrt(0.2),
        joint_damping=0.0,
        body_damping=0.0,
        solver_iterations=30,
        inertia_from_file=True,
        camera_target=(2.5, 0.0, 2.5),
        camera_yaw=150.0,  # from the side away from the torso
        workspace=((0.5, 6.5), (-3.0, 3.0), (0.0, 6.0)),  # palm centre (3.5, 0, 0.5), release at z 5.5
    ),
    "cup": ArmModel(
        urdf="ballcatch.urdf",
        joints=ARM_JOINTS + tuple(f"finger_{f}_{part}" for f in FINGER_NAMES for part in ("proximal", "distal")),
        transmission=JOINT_TRANSMISSION,
        joint_friction=(0.0,) * len(JOINT_TRANSMISSION),
        initial_pose=INITIAL_ARM_POSE + INITIAL_FINGER_POSE * len(FINGER_NAMES),
        ball_radius=BALL_RADIUS,
        ball_mass=BALL_MASS,
        drop_height=DROP_HEIGHT,
        max_torques=MAX_TORQUES,
        friction=1.0,
        restitution=0.0,
        ball_restitution=0.0,
        joint_damping=0.05,
        body_damping=None,
        solver_iterations=30,
        inertia_from_file=False,
        camera_target=(2.2, 0.0, 5.4),
        camera_yaw=25.0,
        workspace=((-0.05, 5.95), (-3.0, 3.0), (0.0, 10.0)),  # palm centre (2.95, 0, 3.92), release at z 8.92
    ),
}
ARM_MODELS = {
    **_PORTED_ARMS,
    "pybrain_held": replace(_PORTED_ARMS["pybrain"], hold_arm=True),
    "pybrain_strong_fingers": replace(_PORTED_ARMS["pybrain"], max_torques=STRONG_FINGER_TORQUES),
}
"""The arm models, by name.

* ``"pybrain"`` (default, :data:`DEFAULT_MODEL`): the arm of the authors' library of the paper's
  time, after PyBrain's ``arm.xode`` (``assets/arm_pybrain.urdf``, whose comment gives the
  geometry): a fixed torso, upper arm hanging from the shoulder, forearm pointing forward, palm
  facing up with its centre 0.5 above the ground at (3.5, 0, 0.5) (the origin is on the ground
  below the shoulder), a thumb and three fingers. Where the paper and ``arm.xode`` differ,
  ``arm.xode`` is followed: the palm is 0.2 thick (paper 0.1) and each finger has three hinges
  (paper two). Every joint has ODE's joint friction (a velocity motor with target 0 and a small
  maximum force, :attr:`ArmModel.joint_friction`) and the action's torques act on top of it
  (pybullet adds ``TORQUE_CONTROL`` torques to the velocity motors). Every finger joint gets the
  whole finger torque, as PyBrain's one-value actuator for several joints applies its value to
  each. Contacts have ODE's friction 8 and bounce 0.2 (pybullet multiplies the two bodies'
  coefficients, so each body gets their square roots), no body damping, a ball of radius 0.4
  and density 10. With zero torque the arm sinks until the hand rests on the ground, the ball
  lands on the open palm, rolls over the fingers and drops (the paper's R ~ -2); closing the
  hand holds it; pulling back drops it at once.
* ``"cup"`` (``assets/ballcatch.urdf``): a fixed pedestal carries a three-joint arm (shoulder,
  elbow, wrist, all hinges about one horizontal axis, so the arm moves in the x-z plane); the
  wrist carries a 1 x 1 x 0.1 palm with four two-joint fingers, one on each palm edge. One
  actuator drives all eight finger joints (proximal joints with its full torque, distal ones
  with :data:`DISTAL_TORQUE_RATIO` of it), so it can only open or close the hand. A ball of
  radius 0.45 is released 5 units above the palm centre. The arm starts in the pose its upper
  joint limits define (upper arm and forearm horizontal, palm tilted 0.15 rad outwards):
  positive torques hold it there, with zero torque it falls. On an open hand the ball rolls onto
  the outer finger and stops against its bent-up tip (return about -1.36, the paper's "kept on
  the fingers" regime); closing the hand, before or after the ball lands, holds it on the palm
  (about -0.93). Torque control only: pybullet's velocity motors are disabled and the action in
  ``[-1, 1]^4`` is scaled by :data:`MAX_TORQUES`.
* ``"pybrain_held"``: ``"pybrain"`` with shoulder, elbow and wrist held at their start angles
  (the action's arm torques are ignored), so the palm stays level at height 0.5. A diagnostic
  (how a policy's hand does on a level palm), not the paper's task.
* ``"pybrain_strong_fingers"``: ``"pybrain"`` with the finger actuator's maximum torque doubled
  (:data:`STRONG_FINGER_TORQUES`). A diagnostic (does the finger actuator's size hold learners
  back?), not the paper's task.
"""

SCRIPTED_WEIGHTS = np.array(
    [
        [2.0, 0.0, 0.0],  # shoulder: tanh(2 x) ~ +1, lift into the limit
        [2.0, 0.0, 0.0],  # elbow
        [2.0, 0.0, 0.0],  # wrist
        [8.8, 0.0, -5.0],  # fingers: close once the ball is below z = 8.8 x / 5 (about 5.2)
    ],
    dtype=np.float64,
)
"""Bias-free linear controller ``u = tanh(W @ ball_xyz)`` that catches the ball (model "cup").

The ball's x coordinate (about 2.95, the palm centre) is nearly constant, so the x column acts as
a bias: the arm joints are pushed into their upper limits and the fingers stay open while the
ball is high and close once its centre is below about z = 5.2, i.e. about 0.8 above its resting
height on the palm (the palm centre is at z = 3.92). An always-closed hand catches as well
(about -0.93); an always-open hand (ball rolls onto the outer finger) scores about -1.36.
"""

PYBRAIN_SCRIPTED_WEIGHTS = np.array(
    [
        [0.0, 0.0, 0.0],  # shoulder, elbow, wrist: no torque, the arm rests on the ground
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0],
        [4.0, 0.0, -7.0],  # fingers: close once the ball is below z = 4 x / 7 (about 2.0)
    ],
    dtype=np.float64,
)
"""Bias-free linear controller ``u = tanh(W @ ball_xyz)`` that catches the ball (model "pybrain").

The ball's x coordinate (about 3.5, the palm centre) acts as a bias again: the hand stays open
while the ball is high and closes once its centre is below about z = 2, about 0.13 s before it lands on
the palm; the closed fingers then hold it (return about -0.93 over seeds 0 to 4). Found by a
small search over the closing height (1.2, 1.6, 2.0, 2.4) and gain (2, 4, 8): every pair
catches (mean returns -0.93 to -1.00 over 4 seeds), height 2.0 with gain 4 best (-0.93, every
seed above -0.95). Closing earlier (below z = 3) lets the closed fingers knock the ball away (about -2.7), as
does a hand closed from the start; an always-open hand gives the zero-torque regime (-2.3).
"""


def scripted_weights(model: str = DEFAULT_MODEL) -> np.ndarray:
    """The hand-written catching controller's weights for an arm model: :data:`SCRIPTED_WEIGHTS`
    (``"cup"``) or :data:`PYBRAIN_SCRIPTED_WEIGHTS` (``"pybrain"`` and its diagnostics).

    Examples:
        >>> scripted_weights("pybrain")[3].tolist()  # only the fingers act
        [4.0, 0.0, -7.0]
    """
    if model not in ARM_MODELS:
        raise ValueError(f"model must be one of {', '.join(ARM_MODELS)}, got {model!r}")
    return SCRIPTED_WEIGHTS if model == "cup" else PYBRAIN_SCRIPTED_WEIGHTS


def scripted_action(observation: Sequence[float], model: str = DEFAULT_MODEL) -> np.ndarray:
    """The hand-written catching controller: ``tanh(W @ ball_xyz)`` with ``W`` =
    :func:`scripted_weights` of ``model``, a bias-free linear map squashed by tanh, i.e. exactly
    the paper's controller class.

    Examples:
        >>> scripted_action([3.5, 0.0, 5.5]).round(3).tolist()  # ball high: hand open
        [0.0, 0.0, 0.0, -1.0]
        >>> scripted_action([2.95, 0.0, 9.0], model="cup").round(3).tolist()  # cup arm: arm up, hand open
        [1.0, 1.0, 1.0, -1.0]
    """
    return np.tanh(scripted_weights(model) @ np.asarray(observation, dtype=np.float64))


