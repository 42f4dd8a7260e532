"""Rollouts of a fixed number of steps through episode boundaries, for PPO and A2C, resumable.

:class:`StepCollector` does what TorchRL's ``Collector(frames_per_batch=n_envs * n_steps,
reset_at_each_iter=False)`` does in one process: the policy acts, the env steps and resets the
done envs alone (``step_and_maybe_reset``), and the state the next rollout starts from is
carried over. Why not ``Collector`` itself: a job must resume bit for bit from a checkpoint, and
the collector's carried state is private (its own ``load_state_dict`` starts fresh trajectories:
"runtime environment state is not generally serializable"). Here the carried tensordict is
:meth:`StepCollector.state_dict`, and the env's state is restored by replay
(:class:`~sde_torchrl.envs.vector.GymVectorEnv`).

For SB3's noise counting without a known rollout length (``schedule="every_n_steps"`` or
``"rollout"`` with ``rollout_steps=None``), the collector redraws the SDE noise at the start of
every rollout (:meth:`~sde_torchrl.modules.noise.SDENoisePrimer.resample`, SB3's ``reset_noise``
at the start of ``collect_rollouts``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sde_torchrl.collectors.fused_steps import fused_env, fused_rollout, tensor_policy
from sde_torchrl.modules.noise import SDENoisePrimer
from sde_torchrl.utils.checks import positive_int
from sde_torchrl.utils.options import ROLLOUT_SCHEDULES


class StepCollector:
    """Collects ``steps`` steps of every env of a batched env per call, through resets.

    Args:
        env: a batched env (batch ``[n_envs]``) whose done envs can be reset alone.
        policy: acts on the env's output (exploring: collection runs under
            ``ExplorationType.RANDOM``).
        steps: steps per env and rollout.
        primer: the env's SDE noise primer, if any: with an SB3-style schedule and no
            ``rollout_steps`` its noise is redrawn at the start of each rollout.
        keep: the keys each collected step keeps (``None``: all). What the trainer, the advantage
            and the loss read is a few vectors per step; the SDE policy's input and output also
            hold ``A × S`` matrices per step (the noise ``ξ``, ``σ̂`` expanded to the batch) that
            none of them reads, and stacking those is most of a rollout's memory. The carried
            state the next rollout starts from keeps everything.
        fast: take the tensor path (:mod:`~sde_torchrl.collectors.fused_steps`) where it applies:
            the same steps without TorchRL's per-step tensordicts; ``False``: always
            ``step_and_maybe_reset``.

    Examples:
        >>> from torchrl.envs import GymEnv
        >>> collector = StepCollector(GymEnv("Pendulum-v1"), lambda td: td.set("action", torch.zeros(1)), 3)
        >>> collector.rollout().batch_size
        torch.Size([3])
        >>> sorted(collector.state_dict())
        ['carried']
        >>> lean = StepCollector(GymEnv("Pendulum-v1"), lambda td: td.set("action", torch.zeros(1)), 3,
        ...                      keep=["action", ("next", "reward")])
        >>> sorted(lean.rollout().keys(True, True), key=str)
        [('next', 'reward'), 'action']
    """

    def __init__(self, env: EnvBase, policy: Any, steps: int, primer: SDENoisePrimer | None = None,
                 keep: Sequence[NestedKey] | None = None, fast: bool = True) -> None:
        self.env, self.policy, self.steps = env, policy, positive_int("steps", steps)
        self.keep = None if keep is None else list(dict.fromkeys(keep))
        self.resample = (primer if primer is not None and primer.schedule in ROLLOUT_SCHEDULES
                         and primer.rollout_steps is None else None)
        self.primer = primer
        self.fast = fast
        self.fused = fused_env(env) if fast else None
        self.carried: TensorDictBase | None = None

    @torch.no_grad()
    def rollout(self) -> TensorDictBase:
        """The next ``steps`` steps of every env, batch ``[*env.batch_size, steps]`` (time last);
        the first call resets every env."""
        if self.carried is None:
            self.carried = self.env.reset()
        elif self.resample is not None:
            self.resample.resample(self.carried)
        with set_exploration_type(ExplorationType.RANDOM):
            if self.fused is not None:
                act = tensor_policy(self.policy)  # the policy may be swapped between rollouts (SAC's warm-up)
                rollout, self.carried = fused_rollout(self.fused, act, self.carried, self.steps, self.keep)
                return rollout
            rows = []
            for _ in range(self.steps):
                step, self.carried = self.env.step_and_maybe_reset(self.policy(self.carried))
                rows.append(step if self.keep is None else step.select(*self.keep, strict=False))
        return torch.stack(rows, dim=-1)

    def state_dict(self) -> dict[str, Any]:
        """The carried state the next rollout starts from, as a nested dict of tensors (``None``
        before the first rollout)."""
        return {"carried": None if self.carried is None else self.carried.to_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Continues from a :meth:`state_dict` (the env must be where it was: see
        :meth:`~sde_torchrl.envs.vector.GymVectorEnv.restore_replay`)."""
        carried = state["carried"]
        self.carried = None if carried is None else TensorDict(carried, batch_size=self.env.batch_size)
        if self.carried is not None and self.primer is not None:
            self.primer.hold(self.carried)  # SB3-style counting keeps ξ through the next partial reset


__all__ = ["StepCollector"]
