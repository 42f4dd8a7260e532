"""The loop of an off-policy algorithm (SAC): collect a few steps into a replay buffer, take
gradient steps on minibatches sampled from it; the loop, evaluations, checkpoints and summary
are every step job's (:class:`~sde_torchrl.trainers.step_job.StepJob`).

As Stable-Baselines3's ``OffPolicyAlgorithm.learn`` with one env: each *round* collects
``train_freq`` steps (:class:`~sde_torchrl.collectors.steps.StepCollector`, through episode
boundaries), adds them to TorchRL's ``ReplayBuffer`` and, once more than ``learning_starts``
steps are collected, takes ``gradient_steps`` gradient steps
(:class:`~sde_torchrl.trainers.sac.SACUpdate`). One *update* of the run directory (a row of
``metrics.csv``, a checkpoint boundary) is ``rounds_per_update`` rounds (:class:`SACTrainer`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.data import LazyTensorStorage, RandomSampler, ReplayBuffer

from sde_torchrl.objectives.sac import TRANSITION_KEYS
from sde_torchrl.trainers.sac import SACUpdate
from sde_torchrl.trainers.step_job import StepJob, StepSettings


@dataclass(frozen=True)
class OffPolicySchedule:
    """When an off-policy job collects and steps (SB3's names).

    Attributes:
        train_freq: env steps collected per round.
        gradient_steps: gradient steps after each round (once learning has started).
        learning_starts: env steps of uniform random actions before learning, a multiple of
            ``train_freq``.
        rounds_per_update: rounds per update (a row of ``metrics.csv``).
        batch_size: transitions per minibatch.
        buffer_size: transitions the replay buffer keeps (the oldest are overwritten).

    Examples:
        >>> OffPolicySchedule(8, 8, 16, 125, 256, 300_000).rounds_before_learning
        2
    """

    train_freq: int
    gradient_steps: int
    learning_starts: int
    rounds_per_update: int
    batch_size: int
    buffer_size: int

    @property
    def rounds_before_learning(self) -> int:
        """Rounds of random actions, without gradient steps after them."""
        return self.learning_starts // self.train_freq


class UniformActions:
    """Acts uniformly at random within ``[low, high]`` (torch's global generator: checkpointed).

    Examples:
        >>> from tensordict import TensorDict
        >>> act = UniformActions(-torch.ones(2), torch.ones(2))
        >>> act(TensorDict({}, [3]))["action"].shape
        torch.Size([3, 2])
    """

    def __init__(self, low: torch.Tensor, high: torch.Tensor) -> None:
        self.low, self.high = low, high

    def __call__(self, tensordict: TensorDictBase) -> TensorDictBase:
        shape = (*tensordict.batch_size, *self.low.shape)
        return tensordict.set("action", self.low + (self.high - self.low) * torch.rand(shape))


class SACTrainer(StepJob):
    """Trains one learner with SAC (the module docstring).

    With an SDE policy the noise is redrawn as a round starts, or every ``sde_sample_freq`` steps
    of the round (SB3's ``collect_rollouts``); the buffer samples uniformly with replacement.
    Until ``learning_starts`` steps are collected the actions are uniform in the action bounds
    (SB3's warm-up with ``use_sde_at_warmup=False``). ``grad_norm`` is the mean norm of the
    actor's gradient over the update's gradient steps (0 before the first), and
    ``sigma_min``/``sigma_max`` are SDE's ``σ̂`` (NaN for the Gaussian, whose ``σ`` depends on
    the state).

    A checkpoint holds, besides what every step job's holds (the modules, every random
    generator, the collector's carried state and the env's replay record), the replay buffer's
    content and write cursor and the three optimisers' states: a resumed job samples the same
    minibatches and writes exactly the rows of an uninterrupted one. The buffer holds the
    transitions' observations, actions, rewards and done flags only
    (:data:`~sde_torchrl.objectives.sac.TRANSITION_KEYS`): on HalfCheetahBullet 300,000 of them
    take about 70 MB in each checkpoint.

    Args:
        collector: collects ``train_freq`` steps of the training env per call.
        eval_env: the evaluation env (batch ``[eval_episodes]``).
        policy: the exploring policy (SDE or Gaussian, tanh-squashed).
        loss: the ``SACLoss`` (it holds the critics and the entropy coefficient).
        update: the gradient step (its optimisers are checkpointed through it).
        settings: the job's :class:`~sde_torchrl.trainers.step_job.StepSettings` (``n_steps``:
            env steps per update).
        schedule: the job's :class:`OffPolicySchedule`.
        warmup: acts until ``learning_starts`` (:class:`UniformActions`).
        logger, check_env: as :class:`~sde_torchrl.trainers.step_job.StepJob` takes them.

    Examples:
        See :func:`sde_torchrl.config.build_sac.build_sac_trainer`.
    """

    #: SAC has no gradient clipping; a larger minibatch steadies its steps.
    nonfinite_remedy = "lower lr or set a larger algorithm.batch_size"

    def __init__(self, collector: Any, eval_env: Any, policy: nn.Module, loss: nn.Module, update: SACUpdate,
                 settings: StepSettings, schedule: OffPolicySchedule, warmup: UniformActions, logger: Any = None,
                 check_env: Any = None) -> None:
        #: the checkpointed modules: the policy, the critics and their targets, α (in ``loss``)
        super().__init__(collector, eval_env, policy, {"policy": policy, "loss": loss}, update, settings,
                         logger=logger, check_env=check_env)
        self.update_step, self.schedule, self.warmup = update, schedule, warmup
        total = settings.updates * schedule.rounds_per_update
        self.buffer = ReplayBuffer(storage=LazyTensorStorage(min(schedule.buffer_size, total * schedule.train_freq)),
                                   sampler=RandomSampler(), batch_size=schedule.batch_size)

    def update(self, k: int) -> dict[str, torch.Tensor]:
        """Update ``k``: its rounds of collection and gradient steps; the row's statistics.

        Raises:
            NonFiniteError: a non-finite training return, gradient or (after the update) parameter.
        """
        norms: list[torch.Tensor] = []
        for r in range(k * self.schedule.rounds_per_update, (k + 1) * self.schedule.rounds_per_update):
            mean = self._collect_round(r)
            if r >= self.schedule.rounds_before_learning:  # SB3: more than learning_starts steps collected
                self.update_step.set_round(r + 1)
                norms += [self.update_step(self.buffer.sample()) for _ in range(self.schedule.gradient_steps)]
        self.check_return(k, mean)
        grad_norm = torch.stack(norms).mean().reshape(1) if norms else torch.zeros(1)
        return self.checked_statistics(k, mean, grad_norm)

    def _collect_round(self, r: int) -> float:
        """Round ``r``'s steps into the buffer; the training return after them."""
        self.collector.policy = self.warmup if r < self.schedule.rounds_before_learning else self.policy
        batch = self.collector.rollout()
        self.buffer.extend(batch.reshape(-1).select(*TRANSITION_KEYS))
        return self.record_returns(batch)

    def rollout_state(self) -> dict[str, Any]:
        return {**super().rollout_state(), "buffer": self.buffer.state_dict()}

    def restore_rollout(self, rollout: dict[str, Any]) -> None:
        super().restore_rollout(rollout)
        self.buffer.load_state_dict(rollout["buffer"])


__all__ = ["OffPolicySchedule", "SACTrainer", "UniformActions"]
