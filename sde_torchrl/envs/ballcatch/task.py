"""The rules of the ball-catching task (paper section 4.2), written once for every form of the
task: the gymnasium env, the batched TorchRL env and the whole-episode path all step their
worlds through :class:`CatchEpisode`.

* **Action**: 4 numbers (shoulder, elbow, wrist, fingers) clipped to ``[-1, 1]``
  (:func:`clip_action`), then scaled to torques by the world
  (:meth:`~sde_torchrl.envs.ballcatch.world.BallCatchWorld.joint_forces`).
* **Ground contact**: the ball has touched the ground once its centre is below
  :attr:`~sde_torchrl.envs.ballcatch.models.ArmModel.ground_z` (``radius + 0.01``: exact for the
  flat ground at ``z = 0`` and cheaper than a contact query). Contact is absorbing: from then on
  the world is frozen (no more physics steps; the observation stays the ball position at
  contact) and every remaining step counts ``-3``. The rewards are exactly those of simulating
  on (they are ``-3`` whatever happens after contact); failed episodes just cost less.
* **Reward** per step (:func:`step_reward`): ``-3`` once the ball has touched the ground,
  otherwise ``-clip(distance(ball centre, palm centre), 0.5, 3)``.
* **Length**: every episode lasts :data:`EPISODE_STEPS` = 500 steps of 0.01 s (truncated, never
  terminated), so the paper's return (mean reward) lies in ``[-3, -0.5]``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

from sde_torchrl.envs.ballcatch.world import BallCatchWorld
from sde_torchrl.envs.registration import EPISODE_STEPS

__all__ = ["EPISODE_STEPS", "CatchEpisode", "clip_action", "step_reward"]

DISTANCE_CAP = 3.0
MIN_DISTANCE = 0.5
GROUND_REWARD = -3.0


def clip_action(action: Iterable[float]) -> list[float]:
    """The action clipped to ``[-1, 1]`` entry by entry (a ``tanh``-squashed action is unchanged).

    Examples:
        >>> clip_action([0.5, -2.0, 3.0, 1.0])
        [0.5, -1.0, 1.0, 1.0]
    """
    return [a if -1.0 <= a <= 1.0 else (1.0 if a > 1.0 else -1.0) for a in action]  # 4x faster than min(max())


def step_reward(ball: Sequence[float], palm: Sequence[float], grounded: bool) -> tuple[float, float]:
    """Paper's per-step reward and the ball-palm distance.

    Returns:
        ``(reward, distance)`` with reward ``-3`` if ``grounded`` else ``-clip(distance, 0.5, 3)``.
        The lower clip (0.5, the smallest distance a non-penetrating ball can have) removes the
        millimetres of transient contact penetration, so rewards always lie in ``[-3, -0.5]``.

    Examples:
        >>> step_reward((0.0, 0.0, 2.0), (0.0, 0.0, 1.0), grounded=False)
        (-1.0, 1.0)
        >>> step_reward((0.0, 0.0, 0.4), (0.0, 0.0, 1.0), grounded=True)[0]
        -3.0
    """
    distance = math.dist(ball, palm)
    reward = GROUND_REWARD if grounded else -min(max(distance, MIN_DISTANCE), DISTANCE_CAP)
    return reward, distance


class CatchEpisode:
    """One world's episode under the task rules: the state the rules need and one step of them.

    Attributes:
        world: the physics.
        length: steps per episode.
        t: steps taken since the reset.
        ball, palm: positions of the ball and palm centres after the last step (or the reset).
        grounded: whether the ball has touched the ground (the world is then frozen).
        distance: ball-palm distance after the last step (or the reset).

    Args:
        world: the physics world.
        length: steps per episode (the paper's 500).

    Examples:
        >>> world = BallCatchWorld()
        >>> episode = CatchEpisode(world)
        >>> episode.reset((0.0, 0.0))
        >>> rewards = [episode.step((0.0, 0.0, 0.0, 0.0)) for _ in range(EPISODE_STEPS)]
        >>> episode.grounded, rewards[-1], episode.truncated  # no torque: the arm falls away
        (True, -3.0, True)
        >>> world.close()
    """

    __slots__ = ("ball", "distance", "grounded", "length", "palm", "t", "world", "_ground_z")

    def __init__(self, world: BallCatchWorld, length: int = EPISODE_STEPS) -> None:
        self.world, self.length = world, length
        self._ground_z = world.config.arm.ground_z
        self.t, self.grounded = 0, False
        self.ball = self.palm = (0.0, 0.0, 0.0)
        self.distance = 0.0

    def reset(self, offset_xy: Sequence[float]) -> None:
        """Start pose; the ball released above the palm, shifted horizontally by ``offset_xy``."""
        world = self.world
        world.reset(offset_xy)
        self.ball, self.palm = world.ball_position(), world.palm_position()
        self.t, self.grounded = 0, False
        self.distance = math.dist(self.ball, self.palm)

    def step(self, action: Iterable[float]) -> float:
        """One step: the clipped ``action`` drives the world unless the ball has touched the
        ground (frozen world), then ground contact is checked and the step scored.

        Args:
            action: 4 finite numbers (shoulder, elbow, wrist, fingers), clipped to ``[-1, 1]``.

        Returns:
            The reward (:func:`step_reward`).
        """
        if not self.grounded:
            self.ball, self.palm = self.world.step(clip_action(action))
            self.grounded = self.ball[2] < self._ground_z
        self.t += 1
        reward, self.distance = step_reward(self.ball, self.palm, self.grounded)
        return reward

    @property
    def truncated(self) -> bool:
        """Whether the episode has run its ``length`` steps."""
        return self.t >= self.length
