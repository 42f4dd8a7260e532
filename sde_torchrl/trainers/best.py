"""Each run's best policy by its periodic evaluations, the way Stable-Baselines3's
``EvalCallback`` keeps ``best_model``: whenever a run's deterministic evaluation beats its best
so far, that run's parameters are copied aside. Runs are independent: with stacked runs (a
leading ``[runs]`` dimension on every per-run tensor) each run keeps its own best.

Choosing the best by a noisy evaluation and reporting that same evaluation overstates it; the
trainers check the best policy on fresh episodes at the job's end (``final_episodes``).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch
from torch import nn

from sde_torchrl.utils.files import write_atomically

#: The file a finished job keeps its runs' best policies in, beside ``summary.json``.
BEST_POLICY = "best_policy.pt"
#: A film of the best run's best policy, where the env can film one (ball catching).
BEST_POLICY_GIF = "best_policy.gif"


class BestPolicy:
    """The best state of each run of ``module`` so far, by evaluation.

    Args:
        module: what is kept (the policy, or a dict of modules whose state dict a policy needs:
            observation statistics, say); its state dict's tensors with a leading ``[runs]``
            dimension are per run, the others shared by all runs.
        runs: the runs trained side by side (1 for PPO, A2C and SAC).

    Examples:
        >>> layer = nn.Linear(1, 1, bias=False)
        >>> best = BestPolicy(layer, runs=1)
        >>> with torch.no_grad():
        ...     _ = layer.weight.fill_(1.0)
        >>> best.observe(0, torch.tensor([-2.0]))
        >>> with torch.no_grad():
        ...     _ = layer.weight.fill_(5.0)
        >>> best.observe(1, torch.tensor([-3.0]))  # worse: the update-0 weights stay
        >>> best.update.tolist(), best.state["weight"].item()
        ([0], 1.0)
    """

    def __init__(self, module: nn.Module, runs: int) -> None:
        self.module, self.runs = module, runs
        self.score = torch.full((runs,), -torch.inf, dtype=torch.float64)
        self.update = torch.full((runs,), -1, dtype=torch.int64)
        self.state = {name: value.detach().clone() for name, value in module.state_dict().items()}

    def observe(self, update: int, evaluation: torch.Tensor) -> None:
        """Keeps, for each run whose ``evaluation`` (``[runs]``) beats its best so far (ties
        keep the earlier policy), the module's current state as that run's best."""
        better = evaluation.detach().cpu().double() > self.score
        if not bool(better.any()):
            return
        self.score = torch.where(better, evaluation.detach().cpu().double(), self.score)
        self.update = torch.where(better, torch.tensor(update), self.update)
        for name, value in self.module.state_dict().items():
            self.state[name] = self._merge(better, value.detach(), self.state[name])

    def _merge(self, better: torch.Tensor, current: torch.Tensor, kept: torch.Tensor) -> torch.Tensor:
        if self.runs == 1 or current.dim() == 0 or current.shape[0] != self.runs:
            return current.clone() if bool(better.all()) or self.runs == 1 else kept
        mask = better.to(current.device).reshape(-1, *([1] * (current.dim() - 1)))
        return torch.where(mask, current, kept)

    @contextmanager
    def loaded(self) -> Iterator[None]:
        """The module holds each run's best state inside the block, its own state again after."""
        own = {name: value.detach().clone() for name, value in self.module.state_dict().items()}
        self.module.load_state_dict(self.state)
        try:
            yield
        finally:
            self.module.load_state_dict(own)

    def state_dict(self) -> dict[str, Any]:
        return {"score": self.score.clone(), "update": self.update.clone(),
                "state": {name: value.clone() for name, value in self.state.items()}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.score, self.update = state["score"].clone(), state["update"].clone()
        self.state = {name: value.clone() for name, value in state["state"].items()}


def write_best_policy(path: Path, state: dict[str, Any]) -> None:
    """Writes a :meth:`BestPolicy.state_dict` as ``best_policy.pt`` (atomically): per run, the
    update whose policy it is (0-based, as ``metrics.csv`` counts) and its evaluation, and the
    state dict to load into the job's policy.

    Examples:
        >>> import tempfile
        >>> best = BestPolicy(nn.Linear(2, 1), runs=1)
        >>> best.observe(4, torch.tensor([-1.0]))
        >>> path = Path(tempfile.mkdtemp()) / BEST_POLICY
        >>> write_best_policy(path, best.state_dict())
        >>> torch.load(path, weights_only=True)["update"]
        [4]
    """
    record = {"update": state["update"].tolist(), "evaluation": state["score"].tolist(),
              "state_dict": state["state"]}
    write_atomically(path, lambda f: torch.save(record, f))


__all__ = ["BEST_POLICY", "BEST_POLICY_GIF", "BestPolicy", "write_best_policy"]
