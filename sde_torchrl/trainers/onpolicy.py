"""The loop of the on-policy algorithms (PPO, A2C): collect a rollout, estimate advantages,
update, evaluate; with the run directory, checkpoints and resume of every job.

Each update (an *iteration* in SB3's words) collects ``n_steps`` steps of each of ``n_envs``
envs through episode boundaries (:class:`~sde_torchrl.collectors.steps.StepCollector`), computes
the advantages (TorchRL's ``GAE``) and hands the batch to the algorithm's update
(:class:`~sde_torchrl.trainers.ppo.PPOUpdate`, :class:`~sde_torchrl.trainers.a2c.A2CUpdate`).
Every ``eval_period`` updates (and after the last) the policy is evaluated without exploration on
``eval_episodes`` fresh episodes, with the observation statistics frozen and raw rewards.

The run directory is the episodic jobs' (:mod:`sde_torchrl.jobs.run_dir`): one ``metrics.csv``
row per update, with

- ``episodes``: training episodes ended so far;
- ``return_mean``: the mean raw return of the last 100 training episodes ended (SB3's
  ``ep_rew_mean``); before the first one ends, the mean return so far of the episodes under way;
- ``eval_return``: the mean deterministic return, where evaluated;
- ``grad_norm``: the mean gradient norm (before clipping) over the update's optimiser steps;
- ``sigma_min``, ``sigma_max``, ``weight_max``: the exploration state
  (:func:`~sde_torchrl.trainers.summary.exploration_state`).

A checkpoint holds, besides the modules (policy, critic, normalisation statistics), the
optimiser and every random generator, what the next rollout starts from: the collector's carried
state and each env's episode seed and actions since its reset, which a resumed job replays
(:meth:`~sde_torchrl.envs.vector.GymVectorEnv.restore_replay`), so that an interrupted job
started again writes exactly the rows of an uninterrupted one.
"""

from __future__ import annotations

import logging
import os
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sde_torchrl.collectors.steps import StepCollector
from sde_torchrl.envs.normalize import RunningNormalize
from sde_torchrl.jobs.checkpoint import job_streams, restore_job, save_job
from sde_torchrl.jobs.metrics import MetricRow, metric_rows, recorded_rows, update_statistics
from sde_torchrl.jobs.run_dir import RunDirectory
from sde_torchrl.trainers.best import BestPolicy
from sde_torchrl.trainers.final_check import run_final_check
from sde_torchrl.trainers.guard import NonFiniteError
from sde_torchrl.trainers.interrupt import DeferredInterrupt
from sde_torchrl.trainers.optim import LearningRateSchedule
from sde_torchrl.trainers.report import Reporter
from sde_torchrl.trainers.summary import LoopState, exploration_state
from sde_torchrl.trainers.trainer import train_in_directory

log = logging.getLogger(__name__)

#: Training episodes ``return_mean`` averages over (SB3's ``stats_window_size``).
RETURN_WINDOW = 100
#: What the loop itself reads of a rollout: which episodes ended, and their raw returns.
RECORDED_KEYS = (("next", "done"), ("next", "episode_reward"))


@dataclass(frozen=True)
class OnPolicySettings:
    """What the on-policy loop reads of a job's config.

    Attributes:
        algorithm: ``"ppo"`` or ``"a2c"`` (a label).
        updates: updates (iterations) of the job.
        n_envs: envs stepped side by side.
        n_steps: steps per env and update.
        eval_period: evaluate every this many updates (and after the last); 0: only after the last.
        eval_episodes: deterministic episodes per evaluation.
        episode_length: the longest episode (the evaluation's rollout length).
        first_run: the run's global index (the ``run`` column).
        final_episodes: fresh deterministic episodes on which the final and the best policies
            are checked at the job's end (0: none).

    Examples:
        >>> OnPolicySettings("ppo", updates=3, n_envs=2, n_steps=8, eval_period=0, eval_episodes=1,
        ...                  episode_length=200).steps_per_update
        16
    """

    algorithm: str
    updates: int
    n_envs: int
    n_steps: int
    eval_period: int
    eval_episodes: int
    episode_length: int
    first_run: int = 0
    final_episodes: int = 0

    @property
    def steps_per_update(self) -> int:
        return self.n_envs * self.n_steps


class EpisodeReturns:
    """The raw returns of the training episodes as they end: their count, and the last
    :data:`RETURN_WINDOW` of them.

    Examples:
        >>> returns = EpisodeReturns()
        >>> returns.add(torch.tensor([1.0, 3.0]))
        >>> returns.count, returns.mean()
        (2, 2.0)
    """

    def __init__(self) -> None:
        self.count, self.window = 0, deque(maxlen=RETURN_WINDOW)

    def add(self, ended: torch.Tensor) -> None:
        self.count += len(ended)
        self.window.extend(float(r) for r in ended)

    def mean(self) -> float | None:
        return sum(self.window) / len(self.window) if self.window else None

    def state_dict(self) -> dict[str, Any]:
        return {"count": self.count, "window": torch.tensor(list(self.window), dtype=torch.float64)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.count = int(state["count"])
        self.window = deque(state["window"].tolist(), maxlen=RETURN_WINDOW)


class OnPolicyTrainer:
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
        settings: the job's :class:`OnPolicySettings`.
        normalizer: the training env's running normalisation (``None``: none).
        eval_normalizer: the evaluation env's frozen copy, refreshed before each evaluation.
        logger: optional TorchRL logger (``log_scalar``); its curves' step is the env steps.
        lr_schedule: sets the learning rate before each update (``None``: constant).
        check_env: makes the final check's env for a number of episodes, on the ``final_eval``
            stream, with its frozen normalisation (``None``: none); needed when
            ``final_episodes > 0``.

    Examples:
        See :func:`sde_torchrl.config.build_onpolicy.build_onpolicy_trainer`.
    """

    #: What a non-finite stop advises (:class:`~sde_torchrl.trainers.guard.NonFiniteError`): settings of the job.
    nonfinite_remedy = "lower lr or set a smaller algorithm.max_grad_norm"

    def __init__(
        self, collector: StepCollector, eval_env: EnvBase, policy: nn.Module, critic: nn.Module,
        advantage: Callable[[TensorDictBase], Any], update: Callable[[TensorDictBase, int], float],
        optimizer: torch.optim.Optimizer, settings: OnPolicySettings, *, normalizer: RunningNormalize | None = None,
        eval_normalizer: RunningNormalize | None = None, logger: Any = None,
        lr_schedule: LearningRateSchedule | None = None,
        check_env: Callable[[int], tuple[EnvBase, RunningNormalize | None]] | None = None,
    ) -> None:
        self.collector, self.eval_env, self.policy, self.critic = collector, eval_env, policy, critic
        self.advantage, self.update_step, self.optimizer, self.settings = advantage, update, optimizer, settings
        self.normalizer, self.eval_normalizer, self.logger, self.lr_schedule = normalizer, eval_normalizer, logger, \
            lr_schedule
        parts = {"policy": policy, "critic": critic, **({"normalizer": normalizer} if normalizer is not None else {})}
        #: Everything a checkpoint saves of the learner, under one state dict.
        self.modules = nn.ModuleDict(parts)
        self.returns = EpisodeReturns()
        self.episodes: list[int] = []
        self.check_env = check_env
        #: The best policy by evaluation, with the observation statistics it acts on.
        self.best = BestPolicy(nn.ModuleDict({name: parts[name] for name in parts if name != "critic"}), 1)

    @property
    def env(self) -> EnvBase:
        return self.collector.env

    def update(self, k: int) -> dict[str, torch.Tensor]:
        """Update ``k``: one rollout, its advantages, the algorithm's update; the row's statistics.

        Raises:
            NonFiniteError: a non-finite training return, gradient or (after the update) parameter.
        """
        batch = self.collector.rollout()
        mean = self._record_returns(batch)
        self._check(k, "return", torch.tensor([mean]))
        with torch.no_grad():
            self.advantage(batch)
        if self.lr_schedule is not None:
            self.lr_schedule.apply(k)
        grad_norm = torch.tensor([self.update_step(batch, k)])
        self._check(k, "gradient norm", grad_norm)
        for name, value in self.modules.state_dict().items():
            self._check(k, "parameter", value, name)
        return {"return_mean": torch.tensor([mean]), "grad_norm": grad_norm,
                "exploration": exploration_state(self.policy, 1)}

    def _record_returns(self, batch: TensorDictBase) -> float:
        """Adds the training episodes a rollout ended to :attr:`returns`; the row's ``return_mean``."""
        done = batch["next", "done"].squeeze(-1)
        self.returns.add(batch["next", "episode_reward"].squeeze(-1)[done])
        mean = self.returns.mean()
        if mean is None:  # no episode has ended yet: the returns so far of those under way
            mean = float(batch["next", "episode_reward"][..., -1, :].mean())
        return mean

    def _check(self, k: int, what: str, value: torch.Tensor, name: str | None = None) -> None:
        """Raises :class:`~sde_torchrl.trainers.guard.NonFiniteError` if ``value`` (``what`` at
        update ``k``; ``name``: the parameter's) is not finite, showing its offending entries."""
        if value.is_floating_point() and not bool(torch.isfinite(value).all()):
            shown, where = offending_entries(value)
            raise NonFiniteError(k, what, [self.settings.first_run], parameter=name, values=shown, detail=where,
                                 remedy=self.nonfinite_remedy)

    def evaluate(self) -> torch.Tensor:
        """Mean raw return of ``eval_episodes`` deterministic episodes, one per env, ``[1]``."""
        episodes = self.deterministic_episodes(self.eval_env, self.eval_normalizer)
        return first_episode_returns(episodes).mean().reshape(1)

    def deterministic_episodes(self, env: EnvBase, frozen: RunningNormalize | None) -> TensorDictBase:
        """One deterministic episode per env of ``env`` (``[envs, T]``, steps past its end
        included), its normalisation ``frozen`` at the training statistics."""
        if frozen is not None:
            stats = {k: v for k, v in self.normalizer.state_dict().items() if k != "returns"}
            frozen.load_state_dict(stats, strict=False)
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            return env.rollout(self.settings.episode_length, self.policy, break_when_any_done=False)

    def final_check(self) -> dict[str, Any]:
        """The final and the best policies on the same ``final_episodes`` fresh episodes
        (:func:`~sde_torchrl.trainers.final_check.run_final_check`)."""
        frozen: dict[int, RunningNormalize | None] = {}

        def make(episodes: int) -> EnvBase:
            env, frozen_stats = self.check_env(episodes)
            frozen[id(env)] = frozen_stats
            return env

        def rollout(env: EnvBase) -> TensorDictBase:
            return self.deterministic_episodes(env, frozen[id(env)]).unsqueeze(0)  # one run

        log.info("checking the final and the best policies on %d fresh episodes", self.settings.final_episodes)
        return run_final_check(make, self.settings.final_episodes, self.settings.eval_episodes, self.best, rollout,
                               first_episode_returns)

    def close(self) -> None:
        for env in (self.env, self.eval_env):
            env.close(raise_if_closed=False)

    # ------------------------------------------------------------------- the job
    def train(
        self, out_dir: str | os.PathLike, labels: dict[str, Any] | None = None, *,
        checkpoint_period: int = 0, progress: bool = False,
    ) -> dict[str, Any]:
        """Runs the job (or resumes it) and writes ``metrics.csv``, ``checkpoint.pt``,
        ``summary.json``, with the guarantees of :meth:`sde_torchrl.trainers.trainer.Trainer.train`.

        Returns:
            The summary (also written to ``summary.json``).
        """
        return train_in_directory(self, out_dir, labels, checkpoint_period, progress)

    def _loop(self, run_dir: RunDirectory, state: LoopState, period: int, progress: bool) -> None:
        s = self.settings
        session_start, session_wall = time.perf_counter(), state.wall_s
        reporter = Reporter(self.logger, s.updates, state.update, s.steps_per_update, progress)
        with run_dir.open_metrics(self._rows(state)) as metrics, DeferredInterrupt() as interrupt:
            try:
                for k in range(state.update, s.updates):
                    stats = self.update(k)
                    self.episodes.append(self.returns.count)
                    state.add(stats)
                    is_last = k == s.updates - 1
                    eval_return = None
                    if is_last or (s.eval_period and (k + 1) % s.eval_period == 0):
                        eval_return = state.evals[k] = self.evaluate()
                        self._check(k, "evaluation return", eval_return)
                        self.best.observe(k, eval_return)
                    statistics = update_statistics(s.first_run, k, self.returns.count, stats, eval_return)
                    metrics.write(metric_rows(statistics))
                    state.update, state.finished = k + 1, is_last
                    state.wall_s = session_wall + time.perf_counter() - session_start
                    reporter.update(k, (k + 1) * s.steps_per_update, statistics)
                    if is_last:
                        break
                    if interrupt.requested or (period and state.update % period == 0):
                        metrics.sync()
                        self._save(run_dir, state)
                    if interrupt.requested:
                        interrupt.stop(state.update, run_dir.path)
            finally:
                reporter.close()
            metrics.sync()
            if s.final_episodes and state.finished:
                state.final_check = self.final_check()
        self._save(run_dir, state)

    def _rows(self, state: LoopState) -> list[MetricRow]:
        """The ``metrics.csv`` rows of the updates ``state`` holds (what a checkpoint recorded)."""
        return recorded_rows(state.record(), self.settings.first_run, self.episodes.__getitem__)

    def _streams(self) -> dict[str, Any]:
        return job_streams(self.modules, self.env, self.eval_env)

    def _save(self, run_dir: RunDirectory, state: LoopState) -> None:
        state.best = self.best.state_dict()
        loop = {**state.state_dict(), "episodes": torch.tensor(self.episodes, dtype=torch.int64),
                "rollout": self._rollout_state()}
        save_job(run_dir.checkpoint, config=run_dir.config, loop=loop, policy=self.modules, optimizer=self.optimizer,
                 streams=self._streams())

    def _rollout_state(self) -> dict[str, Any]:
        """What the next rollout starts from: the collector's carried state, the envs' replay
        record, the training returns."""
        return {"collector": self.collector.state_dict(), "env": self.env.base_env.replay_state(),
                "returns": self.returns.state_dict()}

    def _restore_rollout(self, rollout: dict[str, Any]) -> None:
        """Puts envs, collector and returns back where :meth:`_rollout_state` recorded them."""
        self.env.base_env.restore_replay(rollout["env"])
        self.collector.load_state_dict(rollout["collector"])
        self.returns.load_state_dict(rollout["returns"])

    def _resume(self, run_dir: RunDirectory) -> LoopState:
        if not run_dir.has_checkpoint():
            run_dir.start_new_job()
            return LoopState(update=0, reached=torch.zeros(1, dtype=torch.bool))
        loop = restore_job(run_dir.checkpoint, policy=self.modules, optimizer=self.optimizer,
                           streams=self._streams(), updates=self.settings.updates)
        rollout, self.episodes = loop.pop("rollout"), loop.pop("episodes").tolist()
        state = LoopState.from_state_dict(loop)
        run_dir.check_metrics(self._rows(state), state.finished)
        if state.best is not None:
            self.best.load_state_dict(state.best)
        if not state.finished:
            run_dir.summary.unlink(missing_ok=True)
            self._restore_rollout(rollout)
            run_dir.truncate_logger_csv(state.update * self.settings.steps_per_update)
            log.info("resuming %s after update %d of %d", run_dir.path, state.update, self.settings.updates)
        run_dir.clear_error()
        return state

    def _summary(self, state: LoopState) -> dict[str, Any]:
        """The job's summary: first and last training returns, the final evaluation, the
        episodes and env steps, the wall time (the parameters are in ``checkpoint.pt``)."""
        updates = state.update
        return {
            "runs": 1, "first_run": self.settings.first_run, "settings": asdict(self.settings),
            "updates_done": updates,
            "initial_return": [float(state.returns[0][0])], "final_return": [float(state.returns[-1][0])],
            "final_eval_return": [float(state.evals[updates - 1][0])],
            "episodes": self.episodes[updates - 1], "env_steps": updates * self.settings.steps_per_update,
            "wall_s": state.wall_s, "episode_return": "sum",
        }


def offending_entries(value: torch.Tensor) -> tuple[torch.Tensor, str]:
    """The non-finite entries of ``value`` and, for a tensor of several entries, how many there
    are and where the first is.

    Examples:
        >>> offending_entries(torch.tensor([[1.0, float("inf")], [float("nan"), 2.0]]))
        (tensor([inf, nan]), ' (2 of 4 entries, the first at [0, 1])')
        >>> offending_entries(torch.tensor([float("nan")]))
        (tensor([nan]), '')
    """
    bad = ~torch.isfinite(value.detach())
    if value.numel() == 1:
        return value.detach().reshape(1), ""
    first = bad.nonzero()[0].tolist()
    return value.detach()[bad], f" ({int(bad.sum())} of {value.numel()} entries, the first at {first})"


def first_episode_returns(episodes: TensorDictBase) -> torch.Tensor:
    """Each env's return of its first episode in a rollout ``[..., T]`` that runs past episode
    ends (rewards up to and including the first ``done``), ``[...]``."""
    reward, done = episodes["next", "reward"].squeeze(-1), episodes["next", "done"].squeeze(-1).long()
    first_episode = (done.cumsum(-1) - done) == 0  # up to and including the first done
    return (reward * first_episode).sum(-1)


__all__ = ["RECORDED_KEYS", "EpisodeReturns", "OnPolicySettings", "OnPolicyTrainer", "RETURN_WINDOW",
           "offending_entries"]
