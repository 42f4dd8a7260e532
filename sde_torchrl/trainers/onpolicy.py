"""PPO and A2C: collect a rollout, estimate advantages, update.

Each update (an *iteration* in SB3's words) collects ``n_steps`` steps of each of ``n_envs``
envs through episode boundaries (:class:`~sde_torchrl.collectors.steps.StepCollector`), computes
the advantages (TorchRL's ``GAE``) and hands the batch to the algorithm's update
(:class:`~sde_torchrl.trainers.ppo.PPOUpdate`, :class:`~sde_torchrl.trainers.a2c.A2CUpdate`).
The loop, evaluations, checkpoints and summary are every step job's
(:class:`~sde_torchrl.trainers.step_job.StepJob`). ``metrics.csv``'s ``grad_norm`` is the mean
gradient norm (before clipping) over the update's optimiser steps.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.envs import EnvBase

from sde_torchrl.collectors.steps import StepCollector
from sde_torchrl.envs.normalize import RunningNormalize
from sde_torchrl.trainers.optim import LearningRateSchedule
from sde_torchrl.trainers.step_job import StepJob, StepSettings


class OnPolicyTrainer(StepJob):
    """Trains one learner with an on-policy algorithm (PPO, A2C).

    Args:
        collector: collects each update's rollout from the training env.
        eval_env: the evaluation env (batch ``[eval_episodes]``), with frozen normalisation.
        policy: the exploring policy (the SDE or the Gaussian policy).
        critic: the value network.
        advantage: writes ``advantage`` and ``value_target`` into a rollout (TorchRL's ``GAE``).
        update: the algorithm's update of a rollout with advantages, given the update's index;
            returns the mean gradient norm of its optimiser steps.
        optimizer: the optimiser of policy and critic.
        settings: the job's :class:`~sde_torchrl.trainers.step_job.StepSettings`.
        normalizer, eval_normalizer, logger, check_env: as :class:`~sde_torchrl.trainers.step_job.StepJob` takes them.
        lr_schedule: sets the learning rate before each update (``None``: constant).

    Examples:
        See :func:`sde_torchrl.config.build_onpolicy.build_onpolicy_trainer`.
    """

    nonfinite_remedy = "lower lr or set a smaller algorithm.max_grad_norm"

    def __init__(
        self, collector: StepCollector, eval_env: EnvBase, policy: nn.Module, critic: nn.Module,
        advantage: Callable[[TensorDictBase], Any], update: Callable[[TensorDictBase, int], float],
        optimizer: torch.optim.Optimizer, settings: StepSettings, *, normalizer: RunningNormalize | None = None,
        eval_normalizer: RunningNormalize | None = None, logger: Any = None,
        lr_schedule: LearningRateSchedule | None = None,
        check_env: Callable[[int], tuple[EnvBase, RunningNormalize | None]] | None = None,
    ) -> None:
        super().__init__(collector, eval_env, policy, {"policy": policy, "critic": critic}, optimizer, settings,
                         normalizer=normalizer, eval_normalizer=eval_normalizer, logger=logger, check_env=check_env)
        self.critic, self.advantage, self.update_step, self.lr_schedule = critic, advantage, update, lr_schedule

    def update(self, k: int) -> dict[str, torch.Tensor]:
        """Update ``k``: one rollout, its advantages, the algorithm's update; the row's statistics.

        Raises:
            NonFiniteError: a non-finite training return, gradient or (after the update) parameter.
        """
        batch = self.collector.rollout()
        mean = self.record_returns(batch)
        self.check_return(k, mean)
        with torch.no_grad():
            self.advantage(batch)
        if self.lr_schedule is not None:
            self.lr_schedule.apply(k)
        return self.checked_statistics(k, mean, torch.tensor([self.update_step(batch, k)]))


__all__ = ["OnPolicyTrainer"]
