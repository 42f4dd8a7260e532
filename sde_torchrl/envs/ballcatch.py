"""Ball-catching task of the SDE paper (Rückstieß et al. 2008, section 4.2), rebuilt in pybullet.

A fixed pedestal carries a three-joint arm (shoulder, elbow, wrist; all hinges about the same
horizontal axis, so the arm moves forward-backward and up-down in the x-z plane). The wrist
carries a 1 x 1 x 0.1 palm with four two-joint fingers, one on each palm edge. One actuator
drives all eight finger joints (proximal joints with its full torque, distal joints with 0.4 of
it, a fixed transmission), so it can only open or close the hand. A ball of radius 0.45
is released 5 units above the palm centre; the agent observes the ball's xyz and must catch it.

Physical design (see ``assets/ballcatch.urdf``):

* The arm starts in the catching pose, which is also the pose that the *upper* joint limits
  define: upper arm and forearm horizontal, palm tilted 0.15 rad outwards. Positive torques lift
  the arm into those limits and hold it there; with zero torque the arm falls under gravity and
  the ball drops past it to the ground.
* Because the palm is tilted, a ball landing on an open hand rolls outwards onto the outer
  finger and stops against its bent-up tip, about 1.4 from the palm centre ("kept on the
  fingers but hasn't learned to close the hand", the paper's R ~ -1.5 regime; here about -1.36).
  Closing the hand holds the ball on the palm, inside the cup of closed fingers (closing limits
  proximal 1.2, distal 1.0 rad leave an opening of radius about 0.55 for the 0.45 ball), whether
  it closes before the ball arrives or after it has landed (return about -0.93): the paper's
  "catch" is "closing the hand and holding the ball".
* Torque control only: pybullet's default velocity motors are disabled (force 0) and the
  action in ``[-1, 1]^4`` is scaled by :data:`MAX_TORQUES` (shoulder, elbow, wrist, fingers).

Reward per step (paper): ``-3`` once the ball has touched the ground (and for every later step),
otherwise ``-clip(distance(ball centre, palm centre), 0.5, 3)``. The episode always lasts
:data:`EPISODE_STEPS` = 500 steps of 0.01 s (it is truncated, never terminated), so the
paper's return (mean reward) lies in ``[-3, -0.5]``.

"Touched the ground" is decided from the ball height (centre below ``radius + 0.01``), which is
exact for the flat ground at ``z = 0`` and cheaper than a contact query. Ground contact is
absorbing: from then on the world is frozen (no more physics steps; the observation stays the
ball position at contact) and every remaining step of the 500 counts ``-3``. The rewards are
exactly those of simulating on (they are ``-3`` whatever happens after contact); failed episodes
just cost less to simulate.

Two arm models are available (:attr:`BallCatchConfig.model`, described by an :class:`ArmModel`
each in :data:`ARM_MODELS`; the task rules above are shared):

* ``"cup"`` (default): the model described above (``assets/ballcatch.urdf``).
* ``"pybrain"``: the arm of the authors' library of the paper's time, after PyBrain's
  ``arm.xode`` (``assets/arm_pybrain.urdf``, whose comment gives the geometry): a fixed torso,
  upper arm hanging from the shoulder, forearm pointing forward, palm facing up with its centre
  0.5 above the ground at (3.5, 0, 0.5) (the origin is on the ground below the shoulder), a
  thumb and three fingers. Where the paper and ``arm.xode`` differ, ``arm.xode`` is followed:
  the palm is 0.2 thick (paper 0.1; with the 0.4 ball the paper's minimum distance 0.5 holds)
  and each finger has three hinges (paper two). Every joint has ODE's joint friction (a velocity motor
  with target 0 and a small maximum force, :attr:`ArmModel.joint_friction`) and the action's
  torques act on top of it (pybullet adds ``TORQUE_CONTROL`` torques to the velocity motors: a
  0.4 torque does not move a hinge whose motor holds 0.5, a 1.0 torque moves it as a free 0.5
  would). Contacts have ODE's friction 8 and bounce 0.2 (pybullet multiplies the two bodies'
  coefficients, so each body gets their square roots), no body damping, a ball of radius 0.4 and
  density 10. The hand rests 0.5 above the ground: with zero torque the arm sinks onto it, the
  ball lands on the open palm, rolls over the fingers and drops (the paper's R ~ -2); closing
  the hand holds it; pulling back drops it at once.

Run the demo with ``python -m sde_torchrl.envs.ballcatch --policy scripted --episodes 5``
(``--model pybrain`` for the second arm).
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import pybullet

from sde_torchrl.envs.registration import BALLCATCH_ID, EPISODE_STEPS, register_ballcatch

__all__ = [
    "ARM_MODELS",
    "BALLCATCH_ID",
    "EPISODE_STEPS",
    "GROUND_Z",
    "MAX_TORQUES",
    "PYBRAIN_SCRIPTED_WEIGHTS",
    "SCRIPTED_WEIGHTS",
    "ArmModel",
    "BallCatchConfig",
    "BallCatchEnv",
    "BallCatchWorld",
    "episode_return",
    "register_ballcatch",
    "scripted_action",
    "scripted_weights",
]

ASSETS = Path(__file__).with_name("assets")

TIME_STEP = 0.01
GRAVITY = -9.81
BALL_RADIUS = 0.45
BALL_MASS = 0.5
DROP_HEIGHT = 5.0
DISTANCE_CAP = 3.0
MIN_DISTANCE = 0.5
GROUND_Z = BALL_RADIUS + 0.01
"""The ball counts as having touched the ground once its centre is below this height (model "cup";
each model's is :attr:`ArmModel.ground_z`)."""
GROUND_REWARD = -3.0
MAX_TORQUES = (150.0, 80.0, 30.0, 5.0)
"""Maximum torque (N m) of shoulder, elbow, wrist and the finger actuator (see :func:`joint_torques`)."""

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
saturated controller can then lift the loaded arm and close the hand against gravity and friction."""


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
        ball_mass: default mass of the ball (:attr:`BallCatchConfig.ball_mass`).
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

    @property
    def ground_z(self) -> float:
        """The ball counts as having touched the ground once its centre is below this height."""
        return self.ball_radius + 0.01


ARM_MODELS = {
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
    ),
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
    ),
}
"""The arm models: ``"cup"`` (``assets/ballcatch.urdf``) and ``"pybrain"`` (after PyBrain's
``arm.xode``, ``assets/arm_pybrain.urdf``). Every finger joint of model "pybrain" gets the whole
finger torque, as PyBrain's one-value actuator for several joints applies its value to each."""

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


@dataclass(frozen=True)
class BallCatchConfig:
    """Physical parameters of one ball-catching world.

    The fields left ``None`` take the arm model's value (:class:`ArmModel`) when the config is
    made, so a config always holds the values its world uses (hence ``dataclasses.replace`` of
    ``model`` alone would keep the old model's values: make a new config instead).

    Args:
        jitter: half-width of the uniform horizontal offset (x and y, units) of the ball's release
            point around the spot above the palm centre. Default 0.05.
        model: the arm, a key of :data:`ARM_MODELS` (``"cup"`` or ``"pybrain"``).
        ball_mass: ball mass in kg.
        ball_friction: lateral friction of every body (ball, robot, ground).
        drop_height: release height of the ball centre above the palm centre.
        max_torques: maximum torques (shoulder, elbow, wrist, fingers) that scale the action.
        joint_damping: viscous damping of every joint.
        solver_iterations: pybullet ``numSolverIterations`` (pybullet's default is 50). For
            model "cup", with 25 to 50 the scripted catch, the open hand and the closed hand give
            the same returns (about -0.95, -1.34, -0.94); with 20 the ball on an open hand slides
            further (-1.65). 30 keeps a margin and steps 1.17x faster than 50.

    Examples:
        >>> BallCatchConfig(jitter=0.0).max_torques
        (150.0, 80.0, 30.0, 5.0)
        >>> BallCatchConfig(model="pybrain").max_torques == ARM_MODELS["pybrain"].max_torques
        True
        >>> BallCatchConfig(jitter=-1.0)
        Traceback (most recent call last):
        ...
        ValueError: jitter must lie in [0, 0.4], got -1.0
    """

    jitter: float = 0.05
    model: str = "cup"
    ball_mass: float | None = None
    ball_friction: float | None = None
    drop_height: float | None = None
    max_torques: tuple[float, float, float, float] | None = None
    joint_damping: float | None = None
    solver_iterations: int | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.jitter <= 0.4:
            raise ValueError(f"jitter must lie in [0, 0.4], got {self.jitter}")
        if self.model not in ARM_MODELS:
            raise ValueError(f"model must be one of {', '.join(ARM_MODELS)}, got {self.model!r}")
        arm = self.arm
        defaults = {"ball_mass": arm.ball_mass, "ball_friction": arm.friction, "drop_height": arm.drop_height,
                    "max_torques": arm.max_torques, "joint_damping": arm.joint_damping,
                    "solver_iterations": arm.solver_iterations}
        for name, value in defaults.items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)
        if len(self.max_torques) != 4 or min(self.max_torques) <= 0:
            raise ValueError(f"max_torques must be 4 positive numbers, got {self.max_torques}")
        if self.ball_mass <= 0 or self.drop_height <= 0:
            raise ValueError("ball_mass and drop_height must be positive")

    @property
    def arm(self) -> ArmModel:
        """The arm model's description."""
        return ARM_MODELS[self.model]


class BallCatchWorld:
    """One pybullet world (its own DIRECT physics client) holding arm, hand, ball and ground.

    This is the physics core shared by :class:`BallCatchEnv` and the batched TorchRL env. It is
    not an RL environment itself: it knows nothing about rewards or episode length.

    Args:
        config: physical parameters.
        name: label used in error messages (e.g. ``"world 3"``).

    Examples:
        >>> world = BallCatchWorld()
        >>> world.reset((0.0, 0.0))
        >>> world.step((1.0, 1.0, 1.0, -1.0))
        >>> ball, palm = world.ball_position(), world.palm_position()
        >>> world.close()
    """

    def __init__(self, config: BallCatchConfig | None = None, name: str = "world") -> None:
        self.config = config or BallCatchConfig()
        self.name = name
        self.client = pybullet.connect(pybullet.DIRECT)
        if self.client < 0:
            raise RuntimeError(f"BallCatch {name}: could not start a pybullet DIRECT client")
        try:
            self._build()
        except pybullet.error as err:
            self.close()
            raise RuntimeError(f"BallCatch {name}: building the world failed: {err}") from err
        self._max_torques = np.asarray(self.config.max_torques, dtype=np.float64)
        self._transmission = self.config.arm.transmission

    # ------------------------------------------------------------------ construction
    def _build(self) -> None:
        cid = self.client
        cfg = self.config
        arm = cfg.arm
        pybullet.setGravity(0.0, 0.0, GRAVITY, physicsClientId=cid)
        pybullet.setTimeStep(TIME_STEP, physicsClientId=cid)
        pybullet.setPhysicsEngineParameter(
            numSolverIterations=cfg.solver_iterations, deterministicOverlappingPairs=1, physicsClientId=cid
        )
        self.ground = self._make_ground()
        self.robot = pybullet.loadURDF(
            str(ASSETS / arm.urdf), basePosition=(0, 0, 0), useFixedBase=True,
            flags=pybullet.URDF_USE_INERTIA_FROM_FILE if arm.inertia_from_file else 0, physicsClientId=cid,
        )
        names = {
            pybullet.getJointInfo(self.robot, j, physicsClientId=cid)[1].decode(): j
            for j in range(pybullet.getNumJoints(self.robot, physicsClientId=cid))
        }
        self.joints = [names[j] for j in arm.joints]
        self.palm_link = names["wrist"]  # link index == index of its parent joint; the fingers come after it
        radius = arm.ball_radius
        ball_shape = pybullet.createCollisionShape(pybullet.GEOM_SPHERE, radius=radius, physicsClientId=cid)
        ball_visual = pybullet.createVisualShape(
            pybullet.GEOM_SPHERE, radius=radius, rgbaColor=(0.9, 0.2, 0.15, 1), physicsClientId=cid
        )
        self.ball = pybullet.createMultiBody(
            cfg.ball_mass, ball_shape, ball_visual, basePosition=(0, 0, 10), physicsClientId=cid
        )
        links = range(-1, pybullet.getNumJoints(self.robot, physicsClientId=cid))
        for link in links:
            pybullet.changeDynamics(
                self.robot, link, lateralFriction=cfg.ball_friction, jointDamping=cfg.joint_damping,
                restitution=arm.restitution, physicsClientId=cid,
            )
        pybullet.changeDynamics(
            self.ball, -1, lateralFriction=cfg.ball_friction, rollingFriction=0.0, spinningFriction=0.0,
            restitution=arm.ball_restitution, physicsClientId=cid,
        )
        pybullet.changeDynamics(
            self.ground, -1, lateralFriction=cfg.ball_friction, restitution=arm.restitution, physicsClientId=cid
        )
        if arm.body_damping is not None:
            for body, link in [(self.ball, -1), *((self.robot, link) for link in links)]:
                pybullet.changeDynamics(
                    body, link, linearDamping=arm.body_damping, angularDamping=arm.body_damping, physicsClientId=cid
                )
        # Joint friction (ODE's FMax): velocity motors with target 0 whose force is limited to the
        # friction (0 switches them off); the action's torques act on top of them.
        pybullet.setJointMotorControlArray(
            self.robot, self.joints, pybullet.VELOCITY_CONTROL, targetVelocities=[0.0] * len(self.joints),
            forces=list(arm.joint_friction), physicsClientId=cid,
        )
        for joint, angle in zip(self.joints, arm.initial_pose, strict=True):
            pybullet.resetJointState(self.robot, joint, angle, 0.0, physicsClientId=cid)
        self.palm_home = np.asarray(
            pybullet.getLinkState(self.robot, self.palm_link, computeForwardKinematics=1, physicsClientId=cid)[0]
        )
        self._state_id = pybullet.saveState(physicsClientId=cid)

    def _make_ground(self) -> int:
        cid = self.client
        shape = pybullet.createCollisionShape(pybullet.GEOM_PLANE, physicsClientId=cid)
        visual = pybullet.createVisualShape(
            pybullet.GEOM_BOX, halfExtents=(6, 4, 0.005), rgbaColor=(0.55, 0.7, 0.5, 1),
            visualFramePosition=(1.5, 0, -0.005), physicsClientId=cid,
        )
        return pybullet.createMultiBody(0, shape, visual, physicsClientId=cid)

    # ------------------------------------------------------------------ per-episode / per-step
    def reset(self, offset_xy: Sequence[float]) -> None:
        """Restore the initial pose and put the ball above the palm, shifted by ``offset_xy``."""
        cid = self.client
        try:
            pybullet.restoreState(self._state_id, physicsClientId=cid)
            start = (
                self.palm_home[0] + float(offset_xy[0]),
                self.palm_home[1] + float(offset_xy[1]),
                self.palm_home[2] + self.config.drop_height,
            )
            pybullet.resetBasePositionAndOrientation(self.ball, start, (0, 0, 0, 1), physicsClientId=cid)
            pybullet.resetBaseVelocity(self.ball, (0, 0, 0), (0, 0, 0), physicsClientId=cid)
        except pybullet.error as err:
            raise RuntimeError(f"BallCatch {self.name}: pybullet client {cid} failed on reset: {err}") from err

    def step(self, action: Sequence[float]) -> None:
        """Apply ``action * max_torques`` (fingers share action[3]) for one 0.01 s physics step.

        ``action`` must already be validated (4 finite numbers in [-1, 1]).
        """
        scaled = np.asarray(action, dtype=np.float64) * self._max_torques
        self.step_forces(joint_torques(scaled, self._transmission).tolist())

    def step_forces(self, forces: list[float]) -> None:
        """Apply the joint torques (arm, then the finger joints, as :attr:`ArmModel.joints`) and
        step the physics once."""
        try:
            pybullet.setJointMotorControlArray(
                self.robot, self.joints, pybullet.TORQUE_CONTROL, forces=forces, physicsClientId=self.client
            )
            pybullet.stepSimulation(physicsClientId=self.client)
        except pybullet.error as err:
            raise RuntimeError(
                f"BallCatch {self.name}: pybullet client {self.client} failed on step: {err}"
            ) from err

    def step_and_observe(self, forces: list[float]) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """:meth:`step_forces`, then return ``(ball position, palm position)`` (the batched hot path)."""
        cid = self.client
        try:
            pybullet.setJointMotorControlArray(
                self.robot, self.joints, pybullet.TORQUE_CONTROL, forces=forces, physicsClientId=cid
            )
            pybullet.stepSimulation(physicsClientId=cid)
            ball = pybullet.getBasePositionAndOrientation(self.ball, physicsClientId=cid)[0]
            palm = pybullet.getLinkState(self.robot, self.palm_link, physicsClientId=cid)[0]
        except pybullet.error as err:
            raise RuntimeError(f"BallCatch {self.name}: pybullet client {cid} failed on step: {err}") from err
        return ball, palm

    def ball_position(self) -> tuple[float, float, float]:
        """World position of the ball centre."""
        try:
            return pybullet.getBasePositionAndOrientation(self.ball, physicsClientId=self.client)[0]
        except pybullet.error as err:
            raise RuntimeError(f"BallCatch {self.name}: pybullet client {self.client} is not usable: {err}") from err

    def palm_position(self) -> tuple[float, float, float]:
        """World position of the palm centre (its centre of mass), as of the last physics step."""
        try:
            return pybullet.getLinkState(self.robot, self.palm_link, physicsClientId=self.client)[0]
        except pybullet.error as err:
            raise RuntimeError(f"BallCatch {self.name}: pybullet client {self.client} is not usable: {err}") from err

    def ball_touches_hand(self) -> bool:
        """Whether the ball is in contact with the palm or a finger."""
        contacts = pybullet.getContactPoints(self.ball, self.robot, physicsClientId=self.client)
        return any(c[4] >= self.palm_link for c in contacts)

    def render(self, width: int = 160, height: int = 120) -> np.ndarray:
        """RGB frame ``(height, width, 3)`` uint8 from pybullet's software (tiny) renderer."""
        cid = self.client
        view = pybullet.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=self.config.arm.camera_target, distance=8.0, yaw=self.config.arm.camera_yaw,
            pitch=-12.0, roll=0.0, upAxisIndex=2, physicsClientId=cid,
        )
        proj = pybullet.computeProjectionMatrixFOV(
            fov=60.0, aspect=width / height, nearVal=0.1, farVal=50.0, physicsClientId=cid
        )
        img = pybullet.getCameraImage(
            width, height, view, proj, renderer=pybullet.ER_TINY_RENDERER, physicsClientId=cid
        )
        rgba = np.reshape(np.asarray(img[2], dtype=np.uint8), (height, width, 4))
        return np.ascontiguousarray(rgba[:, :, :3])

    def is_connected(self) -> bool:
        """Whether the physics client is still alive."""
        return self.client >= 0 and bool(pybullet.isConnected(physicsClientId=self.client))

    def close(self) -> None:
        """Disconnect the physics client (idempotent)."""
        if self.client >= 0:
            if pybullet.isConnected(physicsClientId=self.client):
                pybullet.disconnect(physicsClientId=self.client)
            self.client = -1


def joint_torques(
    scaled: np.ndarray, transmission: Sequence[tuple[int, float]] = JOINT_TRANSMISSION
) -> np.ndarray:
    """The joint torques ``[..., joints]`` from the 4 actuator torques ``action * max_torques``
    ``[..., 4]`` (any leading dimensions: one row per world).

    Shoulder, elbow and wrist take theirs directly; the one finger actuator drives every finger
    joint with the fraction of its torque that ``transmission`` (:attr:`ArmModel.transmission`)
    gives: for model "cup" (the default, :data:`JOINT_TRANSMISSION`) every proximal joint its full
    torque and every distal joint :data:`DISTAL_TORQUE_RATIO` of it.
    """
    actuator, gain = zip(*transmission, strict=True)
    return scaled[..., list(actuator)] * np.asarray(gain)


def step_reward(ball: Sequence[float], palm: Sequence[float], grounded: bool) -> tuple[float, float]:
    """Paper's per-step reward and the ball-palm distance.

    Returns:
        ``(reward, distance)`` with reward ``-3`` if ``grounded`` else ``-clip(distance, 0.5, 3)``.
        The lower clip (0.5, the smallest distance a non-penetrating ball can have) removes the
        millimetres of transient contact penetration, so rewards always lie in ``[-3, -0.5]``.
    """
    distance = math.dist(ball, palm)
    reward = GROUND_REWARD if grounded else -min(max(distance, MIN_DISTANCE), DISTANCE_CAP)
    return reward, distance


def validate_action(action: Any) -> np.ndarray:
    """Return ``action`` as a float64 array of shape ``(4,)``, clipped to ``[-1, 1]``.

    Raises:
        ValueError: if the shape is not ``(4,)`` or an entry is not finite.
    """
    arr = np.asarray(action, dtype=np.float64)
    if arr.shape != (4,):
        raise ValueError(f"action must have shape (4,), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"action contains non-finite values: {arr.tolist()}")
    return np.clip(arr, -1.0, 1.0)


class BallCatchEnv(gym.Env):
    """Gymnasium env of the paper's ball-catching task (registered as ``sde_torchrl/BallCatch-v0``).

    Observation: ball centre xyz, float32 ``(3,)``. Action: ``Box(-1, 1, (4,))`` scaled by
    the config's ``max_torques`` (shoulder, elbow, wrist, all fingers). Reward: ``-3`` once the ball has
    touched the ground, else ``-clip(ball-palm distance, 0.5, 3)`` (see :func:`step_reward`).
    Every episode is 500 steps long and ends by truncation (``terminated`` is always False);
    once the ball has touched the ground the world is frozen and each remaining step gives ``-3``.
    ``info`` holds ``distance`` (ball-palm centres), ``held`` (the ball is in contact with the
    palm or a finger and has never touched the ground) and ``grounded``.

    Args:
        render_mode: ``None`` or ``"rgb_array"`` (software renderer, no display needed).
        config: physical parameters; ``BallCatchConfig(jitter=0.0)`` makes every episode identical.
        render_size: ``(width, height)`` of rendered frames.
        model: the arm (``"cup"`` or ``"pybrain"``, :data:`ARM_MODELS`) when no ``config`` is
            given, e.g. ``gymnasium.make("sde_torchrl/BallCatch-v0", model="pybrain")``; with a
            ``config`` it must be ``None`` or the config's model.

    Examples:
        >>> import numpy as np
        >>> env = BallCatchEnv()
        >>> obs, info = env.reset(seed=0)
        >>> total = 0.0
        >>> for _ in range(500):
        ...     obs, r, terminated, truncated, info = env.step(scripted_action(obs))
        ...     total += r
        >>> bool(total / 500 > -1.1), truncated
        (True, True)
        >>> env.close()
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": round(1 / TIME_STEP)}

    def __init__(
        self,
        render_mode: str | None = None,
        config: BallCatchConfig | None = None,
        render_size: tuple[int, int] = (160, 120),
        model: str | None = None,
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if config is not None and model not in (None, config.model):
            raise ValueError(f"model={model!r} contradicts config.model={config.model!r}")
        self.render_mode = render_mode
        self.render_size = render_size
        self.config = config or (BallCatchConfig() if model is None else BallCatchConfig(model=model))
        self._ground_z = self.config.arm.ground_z
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(3,), dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self.world = BallCatchWorld(self.config, name="gym world")
        self._t = 0
        self._grounded = False
        self._ready = False

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Restore the start pose and release the ball above the palm (jittered by ``seed``)."""
        super().reset(seed=seed)
        offset = self.np_random.uniform(-self.config.jitter, self.config.jitter, size=2)
        self.world.reset(offset)
        self._t = 0
        self._grounded = False
        self._ready = True
        ball = self.world.ball_position()
        distance = math.dist(ball, self.world.palm_position())
        return np.asarray(ball, dtype=np.float32), {"distance": distance, "held": False, "grounded": False}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply the torques ``action * max_torques`` for one 0.01 s step.

        Raises:
            ValueError: if ``action`` does not have shape ``(4,)`` or is not finite.
            RuntimeError: if called before :meth:`reset` or the physics client died.
        """
        if not self._ready:
            raise RuntimeError("BallCatchEnv.step called before reset (or after the episode ended)")
        action = validate_action(action)
        if not self._grounded:  # ground contact is absorbing: the world stays frozen
            self.world.step(action)
        self._t += 1
        ball = self.world.ball_position()
        self._grounded = self._grounded or ball[2] < self._ground_z
        reward, distance = step_reward(ball, self.world.palm_position(), self._grounded)
        held = (not self._grounded) and self.world.ball_touches_hand()
        truncated = self._t >= EPISODE_STEPS
        self._ready = not truncated
        info = {"distance": distance, "held": held, "grounded": self._grounded}
        return np.asarray(ball, dtype=np.float32), reward, False, truncated, info

    def render(self) -> np.ndarray | None:
        """An RGB frame (``render_mode="rgb_array"``), else ``None``."""
        if self.render_mode != "rgb_array":
            return None
        return self.world.render(*self.render_size)

    def close(self) -> None:
        """Disconnect the physics client."""
        self.world.close()


def scripted_weights(model: str = "cup") -> np.ndarray:
    """The hand-written catching controller's weights for an arm model: :data:`SCRIPTED_WEIGHTS`
    (``"cup"``) or :data:`PYBRAIN_SCRIPTED_WEIGHTS` (``"pybrain"``)."""
    return {"cup": SCRIPTED_WEIGHTS, "pybrain": PYBRAIN_SCRIPTED_WEIGHTS}[model]


def scripted_action(observation: Sequence[float], model: str = "cup") -> np.ndarray:
    """The hand-written catching controller: ``tanh(W @ ball_xyz)`` with ``W`` =
    :func:`scripted_weights` of ``model``, a bias-free linear map squashed by tanh, i.e. exactly
    the paper's controller class."""
    return np.tanh(scripted_weights(model) @ np.asarray(observation, dtype=np.float64))


def episode_return(
    env: BallCatchEnv, policy: str | Callable[[np.ndarray], np.ndarray], seed: int,
    rng: np.random.Generator | None = None, frames: list | None = None, frame_every: int = 5,
) -> float:
    """Run one episode and return the paper's return (mean reward over the 500 steps).

    Args:
        env: the environment.
        policy: ``"scripted"`` (:func:`scripted_action` of the env's model), ``"zero"``,
            ``"random"``, or a function observation → action.
        seed: reset seed.
        rng: generator for the random policy (defaults to one seeded with ``seed``).
        frames: if given, every ``frame_every``-th rendered frame is appended to it.
        frame_every: frame subsampling.
    """
    if not callable(policy) and policy not in ("scripted", "zero", "random"):
        raise ValueError(f"policy must be 'scripted', 'zero', 'random' or a function, got {policy!r}")
    rng = rng or np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    total, truncated, t = 0.0, False, 0
    while not truncated:
        if callable(policy):
            action = policy(obs)
        elif policy == "scripted":
            action = scripted_action(obs, env.config.model)
        elif policy == "zero":
            action = np.zeros(4)
        else:
            action = rng.uniform(-1.0, 1.0, size=4)
        obs, reward, _, truncated, _ = env.step(action)
        total += reward
        if frames is not None and t % frame_every == 0:
            frames.append(env.render())
        t += 1
    return total / EPISODE_STEPS


def write_gif(frames: Sequence[np.ndarray], path: str | Path, fps: int = 20) -> None:
    """Write RGB frames to an animated GIF with pillow."""
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0, optimize=True)


def main(argv: Sequence[str] | None = None) -> None:
    """CLI demo: run a few episodes and print one JSON line with the returns."""
    parser = argparse.ArgumentParser(description="Ball-catching demo (paper section 4.2) in pybullet.")
    parser.add_argument("--policy", choices=("scripted", "zero", "random"), default="scripted")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0, help="episode i uses seed + i")
    parser.add_argument("--jitter", type=float, default=BallCatchConfig.jitter)
    parser.add_argument("--model", choices=tuple(ARM_MODELS), default=BallCatchConfig.model, help="the arm")
    parser.add_argument("--video", type=str, default=None, help="write the first episode to this GIF")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error("--episodes must be >= 1")
    config = BallCatchConfig(jitter=args.jitter, model=args.model)
    env = BallCatchEnv(render_mode="rgb_array" if args.video else None, config=config)
    rng = np.random.default_rng(args.seed)
    returns, frames = [], [] if args.video else None
    try:
        for i in range(args.episodes):
            returns.append(episode_return(env, args.policy, args.seed + i, rng, frames if i == 0 else None))
    finally:
        env.close()
    if args.video:
        write_gif(frames, args.video)
    out = {
        "model": args.model,
        "policy": args.policy,
        "episodes": args.episodes,
        "seed": args.seed,
        "returns": [round(r, 4) for r in returns],
        "mean_return": round(float(np.mean(returns)), 4),
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
