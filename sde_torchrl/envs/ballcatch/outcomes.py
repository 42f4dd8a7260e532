"""What a ball-catching episode did, read off its tensors: the return's level (paper section 4.2)
and the behaviour behind it, so that a user sees what a policy learned without a video.

* :func:`catch_level`: the paper's levels of the mean reward per step R: a good catch (R ≥ −1.0),
  a catch (R ≥ −1.1), the ball kept on the hand (R ≥ −1.5), slowed down (R ≥ −2) and dropped.
* :func:`catch_outcomes`: per episode, whether the ball touched the ground, the step of its first
  contact, the mean ball-palm distance from then on, whether the hand was closing at the last
  step, and the behaviour they make: **dropped**, **kept on the hand** (not dropped, the hand not
  closing) or **held** (not dropped, the hand closing: "closing the hand and holding the ball").

The first contact is found from the ball's path alone: in free fall its height changes by
``g dt²`` less at every step (pybullet integrates semi-implicitly, and the ball has no drag in
the authors' arm), so the first step whose change of velocity points up is the first step at
which something holds the ball against gravity. Steps after the ball has touched the ground (the
world is frozen there) never count.
"""

from __future__ import annotations

import torch

__all__ = ["BEHAVIOURS", "LEVELS", "LEVEL_NAMES", "catch_level", "catch_outcomes"]

#: The paper's levels of the mean reward per step, best first, and their names.
LEVELS = ((-1.0, "good catch"), (-1.1, "catch"), (-1.5, "on the hand"), (-2.0, "slowed"))
#: Every name :func:`catch_level` gives, best first: the levels, then "dropped" below them all.
LEVEL_NAMES = (*(name for _, name in LEVELS), "dropped")
#: The behaviours, by the code :func:`catch_outcomes` gives them.
BEHAVIOURS = ("dropped", "kept on the hand", "held")


def catch_level(mean_reward: float) -> str:
    """The paper's level of a mean reward per step (section 4.2).

    Examples:
        >>> [catch_level(r) for r in (-0.95, -1.05, -1.3, -1.8, -2.5)]
        ['good catch', 'catch', 'on the hand', 'slowed', 'dropped']
    """
    return next((name for bound, name in LEVELS if mean_reward >= bound), LEVEL_NAMES[-1])


def catch_outcomes(
    ball: torch.Tensor, finger_action: torch.Tensor, reward: torch.Tensor, ground_z: float
) -> dict[str, torch.Tensor]:
    """The behaviour of every episode in a batch.

    Args:
        ball: ball positions ``[*batch, T + 1, 3]`` from the reset on.
        finger_action: the finger actuator's action ``[*batch, T]`` (positive closes the hand).
        reward: per-step rewards ``[*batch, T]``.
        ground_z: the height below which the ball has touched the ground
            (:attr:`~sde_torchrl.envs.ballcatch.models.ArmModel.ground_z`).

    Returns:
        Tensors ``[*batch]``: ``"dropped"`` (bool), ``"first_contact"`` (the step, 1-based, at
        whose end the ball was first held against gravity; 0 if never), ``"hold_distance"`` (mean
        ball-palm distance from the first contact to the end, as the reward clips it; NaN if the
        ball was dropped or never touched), ``"closing"`` (bool, the hand closing at the last
        step) and ``"behaviour"`` (an index into :data:`BEHAVIOURS`).

    Examples:
        >>> z = torch.tensor([[5.0, 4.9, 4.7, 4.4, 4.4, 4.4],  # stopped by the hand in step 4
        ...                   [1.0, 0.8, 0.5, 0.3, 0.3, 0.3]])  # falls to the ground at step 3
        >>> ball = torch.stack([torch.zeros(2, 6), torch.zeros(2, 6), z], -1)
        >>> out = catch_outcomes(ball, torch.ones(2, 5), -torch.full((2, 5), 0.6), ground_z=0.41)
        >>> out["first_contact"].tolist(), [BEHAVIOURS[b] for b in out["behaviour"]]
        ([4, 0], ['held', 'dropped'])
        >>> out["hold_distance"].tolist()[0]
        0.6000000238418579
    """
    height = ball[..., 2]
    grounded = height < ground_z
    dropped = grounded.any(-1)
    lift = height[..., 2:] - 2 * height[..., 1:-1] + height[..., :-2]  # velocity of step t minus step t - 1
    held_up = (lift > 0) & ~grounded[..., 1:-1] & ~grounded[..., 2:]
    steps = torch.arange(2, held_up.shape[-1] + 2, device=ball.device)  # t = 2 .. T
    first = torch.where(held_up, steps, held_up.shape[-1] + 2).amin(-1)
    touched = held_up.any(-1)
    first_contact = torch.where(touched, first, 0)
    after = torch.arange(reward.shape[-1], device=ball.device) >= (first_contact - 1).unsqueeze(-1)
    distance = (-reward).masked_fill(~after, 0.0).sum(-1) / after.sum(-1).clamp(min=1)
    hold_distance = torch.where(touched & ~dropped, distance, torch.nan)
    closing = finger_action[..., -1] > 0
    behaviour = torch.where(dropped, 0, torch.where(closing, 2, 1))
    return {"dropped": dropped, "first_contact": first_contact, "hold_distance": hold_distance,
            "closing": closing, "behaviour": behaviour}

