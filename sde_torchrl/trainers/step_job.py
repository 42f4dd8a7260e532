"""What the PPO, A2C and SAC jobs share: one learner that collects steps through episode
boundaries, and is evaluated on one deterministic episode per evaluation env.

A :class:`StepJob` keeps the training episodes' raw returns as they end (``metrics.csv``'s
``return_mean`` is the mean of the last 100, SB3's ``ep_rew_mean``; before the first one ends, the
mean return so far of the episodes under way), counts them per update (``episodes``), and
checkpoints what the next rollout starts from: the collector's carried state and each env's
episode seed and actions since its reset, which a resumed job replays
(:meth:`~sde_torchrl.envs.vector.GymVectorEnv.restore_replay`), so that an interrupted job
started again writes exactly the rows of an uninterrupted one. Evaluations run with the
observation statistics frozen at the training ones, on raw rewards.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sde_torchrl.collectors.fused_steps import deterministic_policy, fused_env, fused_episodes
from sde_torchrl.collectors.steps import StepCollector
from sde_torchrl.envs.normalize import RunningNormalize
from sde_torchrl.jobs.checkpoint import job_streams
from sde_torchrl.jobs.run_dir import RunDirectory
from sde_torchrl.trainers.best import BestPolicy
from sde_torchrl.trainers.final_check import run_final_check
from sde_torchrl.trainers.guard import check_finite
from sde_torchrl.trainers.job import Job
from sde_torchrl.trainers.report import Reporter
from sde_torchrl.trainers.summary import LoopState, exploration_state

log = logging.getLogger(__name__)

#: Training episodes ``return_mean`` averages over (SB3's ``stats_window_size``).
RETURN_WINDOW = 100
#: What the loop itself reads of a rollout: which episodes ended, and their raw returns.
RECORDED_KEYS = (("next", "done"), ("next", "episode_reward"))


@dataclass(frozen=True)
class StepSettings:
    """What a step job's loop reads of its config (PPO, A2C; SAC with ``n_steps`` its steps per update).

    Attributes:
        algorithm: ``"ppo"``, ``"a2c"`` or ``"sac"`` (a label).
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
        >>> StepSettings("ppo", updates=3, n_envs=2, n_steps=8, eval_period=0, eval_episodes=1,
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


class StepJob(Job):
    """One learner collecting steps: the evaluation, final check, checkpointed rollout state and
    summary of the PPO, A2C and SAC jobs; a subclass writes :meth:`update`.

    Args:
        collector: collects the training env's steps.
        eval_env: the evaluation env (batch ``[eval_episodes]``), with frozen normalisation.
        policy: the exploring policy.
        modules: everything a checkpoint saves of the learner (``policy`` among them).
        optimizer: what a checkpoint saves of the optimisation.
        settings: the job's :class:`StepSettings`.
        normalizer: the training env's running normalisation (``None``: none).
        eval_normalizer: the evaluation env's frozen copy, refreshed before each evaluation.
        logger: optional TorchRL logger (``log_scalar``); its curves' step is the env steps.
        check_env: makes the final check's env for a number of episodes, on the ``final_eval``
            stream, with its frozen normalisation; needed when ``final_episodes > 0``.
    """

    checkpoint_extras = ("episodes", "rollout")

    def __init__(
        self, collector: StepCollector, eval_env: EnvBase, policy: nn.Module, modules: dict[str, nn.Module],
        optimizer: Any, settings: StepSettings, *, normalizer: RunningNormalize | None = None,
        eval_normalizer: RunningNormalize | None = None, logger: Any = None,
        check_env: Callable[[int], tuple[EnvBase, RunningNormalize | None]] | None = None,
    ) -> None:
        self.collector, self.eval_env, self.policy, self.optimizer = collector, eval_env, policy, optimizer
        self.settings, self.normalizer, self.eval_normalizer = settings, normalizer, eval_normalizer
        self.logger, self.check_env, self.runs = logger, check_env, 1
        normalized = {"normalizer": normalizer} if normalizer is not None else {}
        self.modules = nn.ModuleDict({**modules, **normalized})
        self.returns = EpisodeReturns()
        #: Per update, the training episodes ended by its end.
        self.episodes: list[int] = []
        #: The best policy by evaluation, with the observation statistics it acts on.
        self.best = BestPolicy(nn.ModuleDict({"policy": policy, **normalized}), 1)

    @property
    def env(self) -> EnvBase:
        return self.collector.env

    def record_returns(self, batch: TensorDictBase) -> float:
        """Adds the training episodes a rollout ended to :attr:`returns`; the row's ``return_mean``."""
        done = batch["next", "done"].squeeze(-1)
        self.returns.add(batch["next", "episode_reward"].squeeze(-1)[done])
        mean = self.returns.mean()
        if mean is None:  # no episode has ended yet: the returns so far of those under way
            mean = float(batch["next", "episode_reward"][..., -1, :].mean())
        return mean

    def check_return(self, k: int, mean: float) -> None:
        """Update ``k``'s training return, checked finite."""
        check_finite(k, "return", torch.tensor([mean]), 1, self.settings.first_run, self.nonfinite_remedy)

    def checked_statistics(self, k: int, mean: float, grad_norm: torch.Tensor) -> dict[str, torch.Tensor]:
        """Update ``k``'s row statistics, once its gradient norm and parameters are checked
        finite; counts the episodes ended by its end."""
        remedy, first = self.nonfinite_remedy, self.settings.first_run
        check_finite(k, "gradient norm", grad_norm, 1, first, remedy)
        state = self.modules.state_dict()
        floats = [value.reshape(-1) for value in state.values() if value.is_floating_point()]
        if not bool(torch.cat(floats).isfinite().all()):  # one check per update; the culprit named below
            for name, value in state.items():
                check_finite(k, "parameter", value, 1, first, remedy, name)
        self.episodes.append(self.returns.count)
        return {"return_mean": torch.tensor([mean]), "grad_norm": grad_norm,
                "exploration": exploration_state(self.policy, 1)}

    def evaluate(self) -> torch.Tensor:
        """Mean raw return of ``eval_episodes`` deterministic episodes, one per env, ``[1]``."""
        episodes = self.deterministic_episodes(self.eval_env, self.eval_normalizer)
        return first_episode_returns(episodes).mean().reshape(1)

    def deterministic_episodes(self, env: EnvBase, frozen: RunningNormalize | None) -> TensorDictBase:
        """One deterministic episode per env of ``env``, ``[envs, T]``: each env is stepped to its
        episode's end and no further, the rollout ends with the longest episode (an env's rows
        after its end are not its episode's: :func:`first_episode_returns` reads up to each
        env's first ``done``); its normalisation ``frozen`` at the training statistics."""
        if frozen is not None:
            stats = {k: v for k, v in self.normalizer.state_dict().items() if k != "returns"}
            frozen.load_state_dict(stats, strict=False)
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            fused = fused_env(env) if self.collector.fast else None
            if fused is not None and (fused.normalizer is None or not fused.normalizer.update_stats):
                # the same episodes without TorchRL's per-step tensordicts
                return fused_episodes(fused, deterministic_policy(self.policy), self.settings.episode_length)
            return env.rollout(self.settings.episode_length, self.policy, break_when_any_done=False,
                               break_when_all_done=True)

    def final_check(self, run_dir: RunDirectory) -> dict[str, Any]:
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

    def episodes_after(self, k: int) -> int:
        return self.episodes[k]

    def logged_step(self, updates: int) -> int:
        return updates * self.settings.steps_per_update

    def make_reporter(self, done: int, progress: bool) -> Reporter:
        return Reporter(self.logger, self.settings.updates, done, self.settings.steps_per_update, progress)

    def checkpointed(self) -> tuple[nn.Module, dict[str, Any]]:
        return self.modules, job_streams(self.modules, self.env, self.eval_env)

    def save_extras(self, state: LoopState) -> dict[str, Any]:
        return {"episodes": torch.tensor(self.episodes, dtype=torch.int64), "rollout": self.rollout_state()}

    def restore_extras(self, extras: dict[str, Any], state: LoopState) -> None:
        self.episodes = extras["episodes"].tolist()
        if not state.finished:
            self.restore_rollout(extras["rollout"])

    def rollout_state(self) -> dict[str, Any]:
        """What the next rollout starts from: the collector's carried state, the envs' replay
        record, the training returns."""
        return {"collector": self.collector.state_dict(), "env": self.env.base_env.replay_state(),
                "returns": self.returns.state_dict()}

    def restore_rollout(self, rollout: dict[str, Any]) -> None:
        """Puts envs, collector and returns back where :meth:`rollout_state` recorded them."""
        self.env.base_env.restore_replay(rollout["env"])
        self.collector.load_state_dict(rollout["collector"])
        self.returns.load_state_dict(rollout["returns"])

    def summarize(self, state: LoopState) -> dict[str, Any]:
        """First and last training returns, the final evaluation, the episodes and env steps,
        the wall time (the parameters are in ``checkpoint.pt``)."""
        updates = state.update
        return {
            "runs": 1, "first_run": self.settings.first_run, "settings": asdict(self.settings),
            "updates_done": updates,
            "initial_return": [float(state.returns[0][0])], "final_return": [float(state.returns[-1][0])],
            "final_eval_return": [float(state.evals[updates - 1][0])],
            "episodes": self.episodes[updates - 1], "env_steps": updates * self.settings.steps_per_update,
            "wall_s": state.wall_s, "episode_return": "sum",
        }

    def close(self) -> None:
        for env in (self.env, self.eval_env):
            env.close(raise_if_closed=False)


def first_episode_returns(episodes: TensorDictBase) -> torch.Tensor:
    """Each env's return of its first episode in a rollout ``[..., T]`` that runs past episode
    ends (rewards up to and including the first ``done``), ``[...]``."""
    reward, done = episodes["next", "reward"].squeeze(-1), episodes["next", "done"].squeeze(-1).long()
    first_episode = (done.cumsum(-1) - done) == 0  # up to and including the first done
    return (reward * first_episode).sum(-1)


__all__ = ["EpisodeReturns", "StepSettings", "RECORDED_KEYS", "RETURN_WINDOW", "StepJob",
           "first_episode_returns"]
