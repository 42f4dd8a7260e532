"""SAC's gradient step on a sampled minibatch, through TorchRL's ``SACLoss``, in SB3's order.

As Stable-Baselines3's ``SAC.train`` (``sac/sac.py``; the SAC paper: Haarnoja et al. 2018, "Soft
Actor-Critic Algorithms and Applications", its clipped double-Q target, reparameterised actor loss
and learned entropy coefficient with target entropy ``-dim(A)``), each gradient step:

1. with the SDE policy, one fresh standard-normal noise matrix for the whole minibatch and the
   next-state actions of the critic's target (:func:`~sde_torchrl.objectives.sac.fresh_loss_noise`: SB3's
   ``actor.reset_noise()`` at each gradient step);
2. the critic loss and its Adam step: TorchRL's ``Σ_k (Q_k - y)²`` halved to SB3's
   ``½ Σ_k MSE(Q_k, y)``;
3. the actor loss (with the updated critics, their parameters detached) and its Adam step;
4. with ``ent_coef="auto"``, the entropy coefficient's loss and Adam step (the critic and actor
   used the coefficient from before it);
5. the Polyak update of the target critics with ``tau``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.objectives import SACLoss, SoftUpdate

from sde_torchrl.modules.sde import SDEParams
from sde_torchrl.objectives.sac import fresh_loss_noise
from sde_torchrl.trainers.compiler import compiled, inductor_recomputing_boolean_masks
from sde_torchrl.trainers.optim import LearningRateSchedule, make_optimizer


class SACUpdate:
    """SAC's gradient steps in SB3's order (the module docstring), with their three Adam
    optimisers (critic, actor, entropy coefficient) and their learning rate over training.

    Args:
        loss: the ``SACLoss`` (:func:`~sde_torchrl.objectives.sac.make_sac_loss`).
        sde: the policy's :class:`~sde_torchrl.modules.sde.SDEParams` (``None``: the Gaussian).
        lr: the learning rate of the three optimisers.
        tau: the target critics' Polyak coefficient.
        optimizer: the ``optimizer`` config group's entries (:func:`~sde_torchrl.trainers.optim.make_optimizer`:
            Adam's options and the rate's schedule); ``None``: SB3's plain Adam.
        rounds: how many times :meth:`set_round` is called over the job (the schedule's length).
        compile: (``algorithm.compile``) the critic's and the actor's losses, forward and
            backward, go through ``torch.compile`` with
            :func:`~sde_torchrl.trainers.compiler.inductor_recomputing_boolean_masks`, and the Adam
            steps use torch's fused kernel; the noise is drawn outside the compiled graphs, so
            every random stream is the eager step's, and the values agree with it to rounding.

    Returns (when called with a minibatch):
        The norm of the actor's gradient (a 0-d tensor: no synchronisation per step).

    Examples:
        >>> from tensordict import TensorDict
        >>> from torchrl.data import Bounded
        >>> from sde_torchrl.modules.sac_actor import make_sac_networks
        >>> from sde_torchrl.objectives.sac import make_sac_loss
        >>> policy, critic, sde = make_sac_networks(3, Bounded(-1.0, 1.0, shape=(1,)), [8], sde_options={})
        >>> update = SACUpdate(make_sac_loss(policy, critic, 1, gamma=0.99), sde, lr=1e-3, tau=0.02)
        >>> batch = TensorDict({"observation": torch.randn(4, 3), "action": torch.zeros(4, 1), "next": {
        ...     "observation": torch.randn(4, 3), "reward": torch.ones(4, 1),
        ...     "done": torch.zeros(4, 1, dtype=torch.bool), "terminated": torch.zeros(4, 1, dtype=torch.bool)}}, [4])
        >>> bool(update(batch) > 0), sorted(update.state_dict())
        (True, ['actor', 'alpha', 'critic'])
    """

    def __init__(self, loss: SACLoss, sde: SDEParams | None, *, lr: float, tau: float,
                 optimizer: Mapping[str, Any] | None = None, rounds: int = 1, compile: bool = False) -> None:
        self.loss, self.sde = loss, sde
        options = {"_target_": "torch.optim.Adam"} if optimizer is None else optimizer
        groups = {"critic": list(loss.qvalue_network_params.flatten_keys().values()),
                  "actor": list(loss.actor_network_params.flatten_keys().values())}
        if not loss.fixed_alpha:
            groups["alpha"] = [loss.log_alpha]
        made = {name: make_optimizer(params, lr, options, rounds, fused=compile) for name, params in groups.items()}
        self.optimizers = {name: optim for name, (optim, _) in made.items()}
        self.schedules: list[LearningRateSchedule] = [s for _, s in made.values() if s is not None]
        self.target = SoftUpdate(loss, tau=tau)
        self.critic_objective, self.actor_objective = self._critic_objective, self._actor_objective
        if compile:
            self.critic_objective = compiled(self._critic_objective, backend=inductor_recomputing_boolean_masks)
            self.actor_objective = compiled(self._actor_objective, backend=inductor_recomputing_boolean_masks)

    def _critic_objective(self, batch: TensorDictBase) -> torch.Tensor:
        return 0.5 * self.loss.qvalue_v2_loss(batch)[0]  # SB3: 0.5 * Σ_k MSE(Q_k, y); TorchRL: Σ_k (Q_k - y)²

    def _actor_objective(self, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        actor_loss, meta = self.loss.actor_loss(batch)
        return actor_loss, meta["log_prob"]

    def set_round(self, done: int) -> None:
        """Sets the learning rate of the round of gradient steps after ``done`` rounds of
        collection (SB3's schedules read the progress after the round's collection)."""
        for schedule in self.schedules:
            schedule.apply(done)

    def __call__(self, batch: TensorDictBase) -> torch.Tensor:
        if self.sde is not None:
            fresh_loss_noise(batch, self.sde)
        critic, actor, alpha = (self.optimizers.get(name) for name in ("critic", "actor", "alpha"))
        critic_loss = self.critic_objective(batch)
        critic.zero_grad()
        critic_loss.backward()
        critic.step()
        actor_loss, log_prob = self.actor_objective(batch)
        actor.zero_grad()
        actor_loss.backward()
        norm = torch.linalg.vector_norm(torch.stack([
            torch.linalg.vector_norm(p.grad) for group in actor.param_groups for p in group["params"]
            if p.grad is not None]))
        actor.step()
        if alpha is not None:
            alpha.zero_grad()
            self.loss.alpha_loss(log_prob).mean().backward()
            alpha.step()
        self.target.step()
        return norm.detach()

    def state_dict(self) -> dict[str, Any]:
        """The optimisers' state dicts, by name."""
        return {name: optim.state_dict() for name, optim in self.optimizers.items()}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        for name, optim in self.optimizers.items():
            optim.load_state_dict(state[name])


__all__ = ["SACUpdate"]
