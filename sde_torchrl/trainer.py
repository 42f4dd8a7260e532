"""The training loop: collect whole episodes, estimate, update, evaluate, log, save.

Every update collects ``N`` fresh episodes per run (a TensorDict ``[runs, N, T]``), turns them
into one gradient per run with an episodic estimator and takes one plain gradient-ascent step
``θ ← θ + α g`` (eq. 1). Every ``eval_period`` updates (and after the last) each run's policy
is evaluated without exploration. Metrics are appended to ``metrics.csv`` as they come, so a
crash loses nothing that finished; ``summary.json`` and the checkpoint are written atomically.
"""

from __future__ import annotations

import csv
import json
import logging
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from tensordict.nn import TensorDictSequential
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sde_torchrl.estimators import EpisodicEstimator, episode_returns
from sde_torchrl.rollout import tensor_rollout, tensor_step_env

log = logging.getLogger(__name__)

METRIC_FIELDS = ("run", "update", "episodes", "return_mean", "eval_return", "grad_norm")


class NonFiniteError(RuntimeError):
    """A return, gradient or parameter became NaN or infinite."""


@dataclass
class TrainingSettings:
    """What one training job does.

    Attributes:
        updates: number of policy updates.
        episodes_per_update: ``N``, fresh episodes per run feeding one update.
        episode_length: ``T``, steps per episode.
        eval_period: evaluate every this many updates (and after the last); 0 disables
            intermediate evaluation.
        eval_episodes: deterministic episodes per evaluation and run.
        r_lim: convergence threshold: a run has converged at the first update whose mean
            exploratory return exceeds it (``None``: not tracked).
        first_run: global index of the first run (for labelling shards of a sweep).
        stop_at_threshold: end the job once every run has exceeded ``r_lim`` (convergence
            sweeps need nothing after that).
        tensor_rollout: collect by tensor stepping where the env supports it
            (:mod:`sde_torchrl.rollout`); ``False`` forces TorchRL's ``env.rollout``.
    """

    updates: int
    episodes_per_update: int
    episode_length: int
    eval_period: int = 20
    eval_episodes: int = 5
    r_lim: float | None = None
    first_run: int = 0
    stop_at_threshold: bool = False
    tensor_rollout: bool = True

    def __post_init__(self) -> None:
        for name in ("updates", "episodes_per_update", "episode_length", "eval_episodes"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if not isinstance(self.eval_period, int) or self.eval_period < 0:
            raise ValueError(f"eval_period must be a non-negative integer, got {self.eval_period!r}")
        if self.stop_at_threshold and self.r_lim is None:
            raise ValueError("stop_at_threshold needs a convergence threshold r_lim")


class Trainer:
    """Trains ``runs`` independent learners side by side.

    Args:
        env: training env, batch ``[runs, episodes_per_update]``, with the explorer's primer.
        eval_env: evaluation env, batch ``[runs, eval_episodes]``.
        policy: ``TensorDictSequential(actor, explorer)`` with run-stacked parameters.
        estimator: an :class:`~sde_torchrl.estimators.EpisodicEstimator` over ``policy``.
        optimizer: optimiser over the policy's parameters (``SGD(lr=α)`` is eq. 1).
        settings: the job's :class:`TrainingSettings`.
        logger: optional TorchRL logger (``log_scalar``) for run-averaged curves.

    Examples:
        See ``train.py`` and :func:`sde_torchrl.build.build_trainer`.
    """

    def __init__(
        self, env: EnvBase, eval_env: EnvBase, policy: TensorDictSequential,
        estimator: EpisodicEstimator, optimizer: torch.optim.Optimizer,
        settings: TrainingSettings, logger: Any = None,
    ) -> None:
        self.env, self.eval_env, self.policy = env, eval_env, policy
        self.estimator, self.optimizer, self.settings, self.logger = estimator, optimizer, settings, logger
        self.runs = env.batch_size[0]

    def _rollout(self, env: EnvBase) -> Any:
        """Fresh whole episodes on ``env``: by tensor stepping where the env and policy allow
        (same episodes, a fraction of the overhead), else by ``env.rollout``."""
        base = tensor_step_env(env, self.policy) if self.settings.tensor_rollout else None
        with torch.no_grad():
            if base is not None:
                return tensor_rollout(base, self.policy, self.settings.episode_length)
            return env.rollout(self.settings.episode_length, self.policy, break_when_any_done=False)

    def collect(self) -> Any:
        """``N`` fresh exploratory episodes per run, ``[runs, N, T]``."""
        return self._rollout(self.env)

    def evaluate(self) -> torch.Tensor:
        """Mean return of deterministic episodes (no exploration noise) per run, ``[runs]``."""
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            episodes = self._rollout(self.eval_env)
        return episode_returns(episodes).mean(-1)

    def update(self, episodes: Any, update: int) -> dict[str, torch.Tensor]:
        """One estimator pass and one optimiser step; raises :class:`NonFiniteError`."""
        out = self.estimator(episodes)
        self._check_finite(update, "return", out["return_mean"])
        self._check_finite(update, "gradient", out["gradient"])
        self.optimizer.zero_grad(set_to_none=True)
        out["loss_objective"].backward()
        self.optimizer.step()
        for name, param in self.estimator.learnable_parameters().items():
            self._check_finite(update, f"parameter {name}", param)
        return {"return_mean": out["return_mean"], "grad_norm": out["gradient_norm"]}

    @staticmethod
    def _check_finite(update: int, what: str, value: torch.Tensor) -> None:
        if not bool(torch.isfinite(value).all()):
            raise NonFiniteError(f"non-finite {what} at update {update}: {value.detach().flatten()[:8]}")

    def train(self, out_dir: str | os.PathLike, labels: dict[str, Any] | None = None) -> dict[str, Any]:
        """Runs the whole job and writes ``metrics.csv``, ``summary.json``, ``checkpoint.pt``.

        Args:
            out_dir: the run directory (Hydra's output directory in ``train.py``).
            labels: entries that head ``summary.json`` (config choices, seed, the config).

        Returns:
            The summary (also written to ``summary.json``).
        """
        s, out = self.settings, Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        runs = self.runs
        history = {"return_mean": [], "eval": {}}
        start = time.perf_counter()
        with open(out / "metrics.csv", "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=METRIC_FIELDS)
            writer.writeheader()
            reached = torch.zeros(runs, dtype=torch.bool)
            for k in range(s.updates):
                stats = self.update(self.collect(), k)
                history["return_mean"].append(stats["return_mean"])
                if s.r_lim is not None:
                    reached |= stats["return_mean"] > s.r_lim
                is_last = k == s.updates - 1 or (s.stop_at_threshold and bool(reached.all()))
                eval_return = None
                if is_last or (s.eval_period and (k + 1) % s.eval_period == 0):
                    eval_return = self.evaluate()
                    history["eval"][k] = eval_return
                for r in range(runs):
                    writer.writerow({
                        "run": s.first_run + r, "update": k, "episodes": (k + 1) * s.episodes_per_update,
                        "return_mean": float(stats["return_mean"][r]),
                        "eval_return": "" if eval_return is None else float(eval_return[r]),
                        "grad_norm": float(stats["grad_norm"][r]),
                    })
                f.flush()
                self._log(k, stats, eval_return, start)
                if is_last:
                    break
        wall = time.perf_counter() - start
        summary = {**(labels or {}), **self._summary(history, wall)}
        torch.save({"policy": self.policy.state_dict(), "optimizer": self.optimizer.state_dict(),
                    "updates": summary["updates_done"]}, _tmp(out / "checkpoint.pt"))
        os.replace(_tmp(out / "checkpoint.pt"), out / "checkpoint.pt")
        write_json_atomic(out / "summary.json", summary)
        log.info("results in %s", out.resolve())
        return summary

    def _log(self, update: int, stats: dict, eval_return: torch.Tensor | None, start: float) -> None:
        step = (update + 1) * self.settings.episodes_per_update
        if self.logger is not None:
            self.logger.log_scalar("return_mean", float(stats["return_mean"].mean()), step=step)
            if eval_return is not None:
                self.logger.log_scalar("eval_return", float(eval_return.mean()), step=step)
        if eval_return is not None:
            steps = step * self.runs * self.settings.episode_length
            log.info("update %d/%d  return %.3f  eval %.3f  %.0f env steps/s", update + 1,
                     self.settings.updates, float(stats["return_mean"].mean()),
                     float(eval_return.mean()), steps / max(time.perf_counter() - start, 1e-9))

    def _summary(self, history: dict, wall: float) -> dict[str, Any]:
        s = self.settings
        returns = torch.stack(history["return_mean"])  # [updates, runs]
        above = returns > s.r_lim if s.r_lim is not None else torch.zeros_like(returns, dtype=torch.bool)
        first = [int(above[:, r].nonzero()[0]) if bool(above[:, r].any()) else None for r in range(self.runs)]
        updates_done = len(history["return_mean"])
        final_eval = history["eval"][updates_done - 1]
        return {
            "runs": self.runs,
            "first_run": s.first_run,
            "settings": asdict(s),
            "updates_done": updates_done,
            "initial_return": returns[0].tolist(),
            "final_return": returns[-1].tolist(),
            "final_eval_return": final_eval.tolist(),
            "episodes_to_threshold": [None if i is None else (i + 1) * s.episodes_per_update for i in first],
            "final_parameters": {  # named as in checkpoint.pt's policy state dict
                name: p.detach().reshape(self.runs, -1).tolist()
                for name, p in self.policy.named_parameters()
            },
            "env_steps": updates_done * s.episodes_per_update * s.episode_length * self.runs,
            "wall_s": wall,
        }


def _tmp(path: Path) -> Path:
    return path.with_name(path.name + ".tmp")


def write_json_atomic(path: str | os.PathLike, data: dict) -> None:
    """Writes JSON to a temporary file and renames it: readers see all of it or nothing."""
    path = Path(path)
    with open(_tmp(path), "w") as f:
        json.dump(data, f, indent=2)
        f.flush()
        os.fsync(f.fileno())
    os.replace(_tmp(path), path)

