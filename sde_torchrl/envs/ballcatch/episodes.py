"""The whole-episode fast path: one world's episode under a linear controller whose maps are
known before the episode starts (SDE: one map per episode; REX: one per step), with no policy
call per step (:meth:`~sde_torchrl.envs.ballcatch.batched.BatchedBallCatchEnv.linear_episodes`
runs it for every world)."""

from __future__ import annotations

import math
from collections.abc import Sequence

from sde_torchrl.envs.ballcatch.task import CatchEpisode

__all__ = ["linear_episode"]


def linear_episode(
    episode: CatchEpisode, matrices: Sequence[Sequence[float]], squash: bool = True
) -> tuple[list, list, list]:
    """One episode of a freshly reset world under ``u_t = M_t x_t + b_t``, ``x_t`` the ball position.

    The hot loop of the fast path, in plain Python floats (numpy is slower on 3-vectors); each
    step goes through the task rules (:meth:`CatchEpisode.step
    <sde_torchrl.envs.ballcatch.task.CatchEpisode.step>`), as on the step-by-step paths.

    Args:
        episode: the world's episode, just reset.
        matrices: ``[M_t | b_t]`` for every step, each ``4 x 4`` flattened row by row into 16
            floats (the same object repeated for a map fixed per episode); their number is the
            episode length.
        squash: the action is ``tanh(u)`` (else ``u``, which the task rules clip to ``[-1, 1]``).

    Returns:
        The ball positions (``steps + 1``, from the reset on), the pre-squash ``u`` and the
        rewards (``steps`` each), as lists.

    Examples:
        >>> import numpy as np
        >>> from sde_torchrl.envs.ballcatch.models import scripted_weights
        >>> from sde_torchrl.envs.ballcatch.world import BallCatchWorld
        >>> world = BallCatchWorld()
        >>> episode = CatchEpisode(world)
        >>> episode.reset((0.0, 0.0))
        >>> affine = np.hstack([scripted_weights(), np.zeros((4, 1))])  # no offset
        >>> observations, samples, rewards = linear_episode(episode, [affine.ravel().tolist()] * 500)
        >>> len(observations), len(samples), sum(rewards) / 500 > -1.0  # the scripted catch
        (501, 500, True)
        >>> world.close()
    """
    ball = episode.ball
    observations, samples, rewards = [ball], [], []
    step, tanh = episode.step, math.tanh
    for a0, a1, a2, a, b0, b1, b2, b, c0, c1, c2, c, d0, d1, d2, d in matrices:
        x0, x1, x2 = ball
        u = (a0 * x0 + a1 * x1 + a2 * x2 + a, b0 * x0 + b1 * x1 + b2 * x2 + b,
             c0 * x0 + c1 * x1 + c2 * x2 + c, d0 * x0 + d1 * x1 + d2 * x2 + d)
        samples.append(u)
        rewards.append(step([tanh(v) for v in u] if squash else u))
        ball = episode.ball
        observations.append(ball)
    return observations, samples, rewards
