"""The scalar a TorchRL loss module's optimiser step descends (the sum of its ``loss_*`` terms,
eager or compiled), and the clipped step down it.

PPO and A2C step on the sum of the terms their loss writes (surrogate, critic, entropy bonus).
With ``compile=True`` that sum goes through ``torch.compile``, as the ``compile`` option of
TorchRL's own PPO and A2C scripts does: the loss's forward and, through AOTAutograd, its backward
run as generated kernels, without the per-call Python work of the tensordict modules. The first
call compiles (tens of seconds); the values agree with the eager ones to rounding, not bit for
bit, and a job is compiled or eager from its first update to its last (the option is part of its
config), so a resumed job repeats an uninterrupted one exactly.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import TensorDictBase
from torchrl.objectives import LossModule

from sde_torchrl.trainers.compiler import compiled


def loss_objective(loss: LossModule, *, compile: bool = False) -> Callable[[TensorDictBase], torch.Tensor]:
    """``batch -> Σ_k loss_k(batch)`` over the ``loss_*`` entries ``loss`` writes.

    Args:
        loss: a TorchRL loss module (``ClipPPOLoss``, ``A2CLoss``, ...).
        compile: go through ``torch.compile`` (forward and backward graphs).

    Returns:
        The objective, a scalar tensor with the loss's graph.

    Examples:
        >>> from tensordict import TensorDict
        >>> from torchrl.modules import MLP, ValueOperator
        >>> from sde_torchrl import MLPActor
        >>> from sde_torchrl.modules.gaussian import make_gaussian_actor
        >>> from sde_torchrl.objectives.actor_critic import make_a2c_loss
        >>> policy = make_gaussian_actor(MLPActor(3, 1, [8], activation="tanh"), 1)
        >>> critic = ValueOperator(MLP(in_features=3, out_features=1, num_cells=[8]), in_keys=["observation"])
        >>> objective = loss_objective(make_a2c_loss(policy, critic, ent_coef=0.0, vf_coef=0.5))
        >>> batch = TensorDict({"observation": torch.randn(4, 3), "action": torch.randn(4, 1),
        ...                     "advantage": torch.randn(4, 1), "value_target": torch.randn(4, 1)}, [4])
        >>> objective(batch).shape
        torch.Size([])
    """

    def objective(batch: TensorDictBase) -> torch.Tensor:
        out = loss(batch)
        return sum(value for key, value in out.items() if key.startswith("loss_"))

    return compiled(objective) if compile else objective


def clipped_step(objective: torch.Tensor, optimizer: torch.optim.Optimizer, parameters: list[torch.Tensor],
                 max_grad_norm: float) -> torch.Tensor:
    """One optimiser step down ``objective``, the gradient's norm clipped to ``max_grad_norm``
    (SB3's ``clip_grad_norm_`` before ``optimizer.step()``); the norm before clipping.

    Examples:
        >>> w = torch.nn.Parameter(torch.tensor([3.0, 4.0]))
        >>> norm = clipped_step((w ** 2).sum() / 2, torch.optim.SGD([w], lr=1.0), [w], max_grad_norm=1.0)
        >>> float(norm), [round(x, 4) for x in w.tolist()]  # w - g / |g| with g = w = (3, 4)
        (5.0, [2.4, 3.2])
    """
    optimizer.zero_grad()
    objective.backward()
    norm = torch.nn.utils.clip_grad_norm_(parameters, max_grad_norm)
    optimizer.step()
    return norm


__all__ = ["clipped_step", "loss_objective"]
