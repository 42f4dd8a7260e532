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

Run the demo with ``python -m sde_torchrl.envs.ballcatch --policy scripted --episodes 5``.
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
    "BALLCATCH_ID",
    "EPISODE_STEPS",
    "GROUND_Z",
    "MAX_TORQUES",
    "SCRIPTED_WEIGHTS",
    "BallCatchConfig",
    "BallCatchEnv",
    "BallCatchWorld",
    "episode_return",
    "register_ballcatch",
    "scripted_action",
]

URDF_PATH = Path(__file__).with_name("assets") / "ballcatch.urdf"

TIME_STEP = 0.01
GRAVITY = -9.81
BALL_RADIUS = 0.45
BALL_MASS = 0.5
DROP_HEIGHT = 5.0
DISTANCE_CAP = 3.0
MIN_DISTANCE = 0.5
GROUND_Z = BALL_RADIUS + 0.01
"""The ball counts as having touched the ground once its centre is below this height."""
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

SCRIPTED_WEIGHTS = np.array(
    [
        [2.0, 0.0, 0.0],  # shoulder: tanh(2 x) ~ +1, lift into the limit
        [2.0, 0.0, 0.0],  # elbow
        [2.0, 0.0, 0.0],  # wrist
        [8.8, 0.0, -5.0],  # fingers: close once the ball is below z = 8.8 x / 5 (about 5.2)
    ],
    dtype=np.float64,
)
"""Bias-free linear controller ``u = tanh(W @ ball_xyz)`` that catches the ball.

The ball's x coordinate (about 2.95, the palm centre) is nearly constant, so the x column acts as
a bias: the arm joints are pushed into their upper limits and the fingers stay open while the
ball is high and close once its centre is below about z = 5.2, i.e. about 0.8 above its resting
height on the palm (the palm centre is at z = 3.92). An always-closed hand catches as well
(about -0.93); an always-open hand (ball rolls onto the outer finger) scores about -1.36.
"""


@dataclass(frozen=True)
class BallCatchConfig:
    """Physical parameters of one ball-catching world.

    Args:
        jitter: half-width of the uniform horizontal offset (x and y, units) of the ball's release
            point around the spot 5 units above the palm centre. Default 0.05.
        ball_mass: ball mass in kg.
        ball_friction: lateral friction of ball, palm and fingers.
        drop_height: release height of the ball centre above the palm centre.
        max_torques: maximum torques (shoulder, elbow, wrist, fingers) that scale the action.
        joint_damping: viscous damping of every joint.
        solver_iterations: pybullet ``numSolverIterations`` (pybullet's default is 50). With 25
            to 50 the scripted catch, the open hand and the closed hand give the same returns
            (about -0.95, -1.34, -0.94); with 20 the ball on an open hand slides further
            (-1.65). 30 keeps a margin and steps 1.17x faster than 50.

    Examples:
        >>> BallCatchConfig(jitter=0.0).max_torques
        (150.0, 80.0, 30.0, 5.0)
        >>> BallCatchConfig(jitter=-1.0)
        Traceback (most recent call last):
        ...
        ValueError: jitter must lie in [0, 0.4], got -1.0
    """

    jitter: float = 0.05
    ball_mass: float = BALL_MASS
    ball_friction: float = 1.0
    drop_height: float = DROP_HEIGHT
    max_torques: tuple[float, float, float, float] = MAX_TORQUES
    joint_damping: float = 0.05
    solver_iterations: int = 30

    def __post_init__(self) -> None:
        if not 0.0 <= self.jitter <= 0.4:
            raise ValueError(f"jitter must lie in [0, 0.4], got {self.jitter}")
        if len(self.max_torques) != 4 or min(self.max_torques) <= 0:
            raise ValueError(f"max_torques must be 4 positive numbers, got {self.max_torques}")
        if self.ball_mass <= 0 or self.drop_height <= 0:
            raise ValueError("ball_mass and drop_height must be positive")


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

    # ------------------------------------------------------------------ construction
    def _build(self) -> None:
        cid = self.client
        cfg = self.config
        pybullet.setGravity(0.0, 0.0, GRAVITY, physicsClientId=cid)
        pybullet.setTimeStep(TIME_STEP, physicsClientId=cid)
        pybullet.setPhysicsEngineParameter(
            numSolverIterations=cfg.solver_iterations, deterministicOverlappingPairs=1, physicsClientId=cid
        )
        self.ground = self._make_ground()
        self.robot = pybullet.loadURDF(
            str(URDF_PATH), basePosition=(0, 0, 0), useFixedBase=True, physicsClientId=cid
        )
        names = {
            pybullet.getJointInfo(self.robot, j, physicsClientId=cid)[1].decode(): j
            for j in range(pybullet.getNumJoints(self.robot, physicsClientId=cid))
        }
        fingers = [names[f"finger_{f}_{part}"] for f in FINGER_NAMES for part in ("proximal", "distal")]
        self.arm_joints = [names[j] for j in ARM_JOINTS]
        self.finger_joints = fingers
        self.joints = self.arm_joints + fingers
        self.palm_link = names["wrist"]  # link index == index of its parent joint
        ball_shape = pybullet.createCollisionShape(pybullet.GEOM_SPHERE, radius=BALL_RADIUS, physicsClientId=cid)
        ball_visual = pybullet.createVisualShape(
            pybullet.GEOM_SPHERE, radius=BALL_RADIUS, rgbaColor=(0.9, 0.2, 0.15, 1), physicsClientId=cid
        )
        self.ball = pybullet.createMultiBody(
            cfg.ball_mass, ball_shape, ball_visual, basePosition=(0, 0, 10), physicsClientId=cid
        )
        for link in [-1, *self.joints]:
            pybullet.changeDynamics(
                self.robot, link, lateralFriction=cfg.ball_friction, jointDamping=cfg.joint_damping,
                physicsClientId=cid,
            )
        pybullet.changeDynamics(
            self.ball, -1, lateralFriction=cfg.ball_friction, rollingFriction=0.0, spinningFriction=0.0,
            restitution=0.0, physicsClientId=cid,
        )
        # Torque control: switch off the default velocity motors once and for all.
        pybullet.setJointMotorControlArray(
            self.robot, self.joints, pybullet.VELOCITY_CONTROL, forces=[0.0] * len(self.joints),
            physicsClientId=cid,
        )
        pose = list(INITIAL_ARM_POSE) + list(INITIAL_FINGER_POSE) * len(FINGER_NAMES)
        for joint, angle in zip(self.joints, pose):
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
        ground = pybullet.createMultiBody(0, shape, visual, physicsClientId=cid)
        pybullet.changeDynamics(ground, -1, lateralFriction=1.0, physicsClientId=cid)
        return ground

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
        self.step_forces(joint_torques(np.asarray(action, dtype=np.float64) * self._max_torques).tolist())

    def step_forces(self, forces: list[float]) -> None:
        """Apply 11 joint torques (arm, then the 8 finger joints) and step the physics once."""
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

    def joint_angles(self) -> np.ndarray:
        """Current angles of the 11 joints (shoulder, elbow, wrist, then the fingers)."""
        states = pybullet.getJointStates(self.robot, self.joints, physicsClientId=self.client)
        return np.array([s[0] for s in states])

    def render(self, width: int = 160, height: int = 120) -> np.ndarray:
        """RGB frame ``(height, width, 3)`` uint8 from pybullet's software (tiny) renderer."""
        cid = self.client
        view = pybullet.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=(2.2, 0.0, 5.4), distance=8.0, yaw=25.0, pitch=-12.0, roll=0.0, upAxisIndex=2,
            physicsClientId=cid,
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


def joint_torques(scaled: np.ndarray) -> np.ndarray:
    """The 11 joint torques ``[..., 11]`` from the 4 actuator torques ``action * max_torques``
    ``[..., 4]`` (any leading dimensions: one row per world).

    Shoulder, elbow and wrist take theirs directly; the one finger actuator drives every proximal
    finger joint with its full torque and every distal joint with :data:`DISTAL_TORQUE_RATIO` of it
    (:data:`JOINT_TRANSMISSION`).
    """
    actuator, gain = zip(*JOINT_TRANSMISSION)
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
    :data:`MAX_TORQUES` (shoulder, elbow, wrist, all fingers). Reward: ``-3`` once the ball has
    touched the ground, else ``-clip(ball-palm distance, 0.5, 3)`` (see :func:`step_reward`).
    Every episode is 500 steps long and ends by truncation (``terminated`` is always False);
    once the ball has touched the ground the world is frozen and each remaining step gives ``-3``.
    ``info`` holds ``distance`` (ball-palm centres), ``held`` (the ball is in contact with the
    palm or a finger and has never touched the ground) and ``grounded``.

    Args:
        render_mode: ``None`` or ``"rgb_array"`` (software renderer, no display needed).
        config: physical parameters; ``BallCatchConfig(jitter=0.0)`` makes every episode identical.
        render_size: ``(width, height)`` of rendered frames.

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
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.render_size = render_size
        self.config = config or BallCatchConfig()
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
        """Apply the torques ``action * MAX_TORQUES`` for one 0.01 s step.

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
        self._grounded = self._grounded or ball[2] < GROUND_Z
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


def scripted_action(observation: Sequence[float]) -> np.ndarray:
    """The hand-written catching controller: ``tanh(SCRIPTED_WEIGHTS @ ball_xyz)``, a bias-free
    linear map squashed by tanh, i.e. exactly the paper's controller class."""
    return np.tanh(SCRIPTED_WEIGHTS @ np.asarray(observation, dtype=np.float64))


def episode_return(
    env: BallCatchEnv, policy: str | Callable[[np.ndarray], np.ndarray], seed: int,
    rng: np.random.Generator | None = None, frames: list | None = None, frame_every: int = 5,
) -> float:
    """Run one episode and return the paper's return (mean reward over the 500 steps).

    Args:
        env: the environment.
        policy: ``"scripted"``, ``"zero"``, ``"random"``, or a function observation → action.
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
            action = scripted_action(obs)
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
    parser.add_argument("--video", type=str, default=None, help="write the first episode to this GIF")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error("--episodes must be >= 1")
    env = BallCatchEnv(render_mode="rgb_array" if args.video else None, config=BallCatchConfig(jitter=args.jitter))
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
        "policy": args.policy,
        "episodes": args.episodes,
        "seed": args.seed,
        "returns": [round(r, 4) for r in returns],
        "mean_return": round(float(np.mean(returns)), 4),
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
