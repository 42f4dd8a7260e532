"""The physics of ball catching: one pybullet world per :class:`BallCatchWorld`, built from a
:class:`BallCatchConfig` (an arm model of :data:`~sde_torchrl.envs.ballcatch.models.ARM_MODELS`
and its physical parameters).

A world knows arm, hand, ball and ground, how the 4 actuators drive the joints
(:meth:`BallCatchWorld.joint_forces`) and how to step and observe; it knows nothing of rewards, ground contact
or episode length (:mod:`~sde_torchrl.envs.ballcatch.task`).
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet

from sde_torchrl.envs.ballcatch.models import ARM_JOINTS, ARM_MODELS, DEFAULT_MODEL, ArmModel

__all__ = ["TIME_STEP", "BallCatchConfig", "BallCatchWorld"]

ASSETS = Path(__file__).parents[1] / "assets"

TIME_STEP = 0.01
"""Seconds per physics step (the paper's 0.01 s)."""
GRAVITY = -9.81
HOLD_FORCE = 1e6
"""Maximum force of the position motors that hold the arm of a model with ``hold_arm``: far
above the largest torque (600) and the loaded arm's weight torque (about 400)."""


@dataclass(frozen=True)
class BallCatchConfig:
    """Physical parameters of one ball-catching world.

    The fields left ``None`` take the arm model's value (:class:`ArmModel`) when the config is
    made, so a config always holds the values its world uses (hence ``dataclasses.replace`` of
    ``model`` alone would keep the old model's values: make a new config instead).

    Args:
        jitter: half-width of the uniform horizontal offset (x and y, units) of the ball's release
            point around the spot above the palm centre. Default 0.05.
        model: the arm, a key of :data:`~sde_torchrl.envs.ballcatch.models.ARM_MODELS`:
            ``"pybrain"`` (the default, after the authors' ``arm.xode``), ``"cup"`` or a
            diagnostic: ``"pybrain_held"`` (the pybrain arm with its arm joints held) or
            ``"pybrain_strong_fingers"`` (its finger actuator doubled).
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
        >>> BallCatchConfig().model
        'pybrain'
        >>> BallCatchConfig(jitter=0.0, model="cup").max_torques
        (150.0, 80.0, 30.0, 5.0)
        >>> BallCatchConfig().max_torques == ARM_MODELS["pybrain"].max_torques
        True
        >>> BallCatchConfig(jitter=-1.0)
        Traceback (most recent call last):
        ...
        ValueError: jitter must lie in [0, 0.4], got -1.0
    """

    jitter: float = 0.05
    model: str = DEFAULT_MODEL
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

    The physics core under every form of the task (the gymnasium env, the batched TorchRL env,
    the whole-episode path), which all step it through
    :class:`~sde_torchrl.envs.ballcatch.task.CatchEpisode`. It is not an RL environment itself:
    it knows nothing about rewards, ground contact or episode length.

    Args:
        config: physical parameters.
        name: label used in error messages (e.g. ``"world 3"``).

    Examples:
        >>> world = BallCatchWorld()
        >>> world.reset((0.0, 0.0))
        >>> ball, palm = world.step((1.0, 1.0, 1.0, -1.0))
        >>> ball == world.ball_position() and palm == world.palm_position()
        True
        >>> world.close()
    """

    def __init__(self, config: BallCatchConfig | None = None, name: str = "world") -> None:
        self.config = config or BallCatchConfig()
        self.name = name
        self.client = pybullet.connect(pybullet.DIRECT)
        if self.client < 0:
            raise RuntimeError(f"BallCatch {name}: could not start a pybullet DIRECT client")
        # A world dropped without close() still frees its physics client (~29 MB) when collected.
        self._disconnect = weakref.finalize(self, _disconnect, self.client)
        try:
            self._build()
        except pybullet.error as err:
            self.close()
            raise RuntimeError(f"BallCatch {name}: building the world failed: {err}") from err
        torques, held = self.config.max_torques, self.config.arm.hold_arm
        # per joint: its actuator, that actuator's maximum torque and the joint's share of it
        # (none for the arm's three joints when the model holds them)
        self._drive = tuple((a, float(torques[a]), 0.0 if held and a < len(ARM_JOINTS) else gain)
                            for a, gain in self.config.arm.transmission)

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
        if arm.hold_arm:  # position motors on the arm joints; the action's torques act on top of them
            held = len(ARM_JOINTS)
            pybullet.setJointMotorControlArray(
                self.robot, self.joints[:held], pybullet.POSITION_CONTROL,
                targetPositions=list(arm.initial_pose[:held]), forces=[HOLD_FORCE] * held, physicsClientId=cid,
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
        if self.client < 0:
            raise RuntimeError(f"BallCatch {self.name} is closed (close() ended its physics client): make a new env")
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

    def joint_forces(self, action: Sequence[float]) -> list[float]:
        """The joint torques (arm, then the finger joints, as :attr:`ArmModel.joints`) for an
        action in ``[-1, 1]^4``: the actuator torques ``action * max_torques``, each joint taking
        the fraction of its actuator's torque that :attr:`ArmModel.transmission` gives (model
        "cup": every proximal finger joint the full finger torque, every distal one
        :data:`~sde_torchrl.envs.ballcatch.models.DISTAL_TORQUE_RATIO` of it)."""
        return [action[actuator] * torque * gain for actuator, torque, gain in self._drive]

    def step(self, action: Sequence[float]) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Apply the torques of ``action`` (:meth:`joint_forces`) for one 0.01 s physics step.

        ``action`` must already be clipped (4 finite numbers in ``[-1, 1]``).

        Returns:
            ``(ball position, palm position)`` after the step.
        """
        return self.step_forces(self.joint_forces(action))

    def step_forces(self, forces: list[float]) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Apply the joint torques ``forces`` (:meth:`joint_forces`), step the physics once and
        return ``(ball position, palm position)``."""
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

    def joint_angles(self) -> dict[str, float]:
        """Angle (rad) of every actuated joint, by name (:attr:`ArmModel.joints`).

        Examples:
            >>> world = BallCatchWorld()
            >>> world.reset((0.0, 0.0))
            >>> world.joint_angles()["index_0"], len(world.joint_angles())
            (0.0, 15)
            >>> world.close()
        """
        try:
            states = pybullet.getJointStates(self.robot, list(self.joints), physicsClientId=self.client)
        except pybullet.error as err:
            raise RuntimeError(f"BallCatch {self.name}: pybullet client {self.client} is not usable: {err}") from err
        return {name: state[0] for name, state in zip(self.config.arm.joints, states, strict=True)}

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
            self._disconnect()
            self.client = -1


def _disconnect(client: int) -> None:
    """Ends a pybullet client if it is still connected."""
    if pybullet.isConnected(physicsClientId=client):
        pybullet.disconnect(physicsClientId=client)

