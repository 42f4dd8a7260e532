"""The episodic estimators' trainer: collect whole episodes, estimate, update.

Every update collects ``N`` fresh episodes per run (a TensorDict ``[runs, N, T]``; or renews the
episode queue, :mod:`sde_torchrl.collectors.episode_queue`), turns them into one gradient per run
with an episodic estimator and takes one optimiser step: with ``SGD(lr=α)``, the paper's plain
gradient ascent ``θ ← θ + α g`` (eq. 1); momentum, Adam and a decaying rate are options
(:mod:`sde_torchrl.trainers.optim`). The non-finite guard (:mod:`~sde_torchrl.trainers.guard`)
checks every update; the loop, evaluations, checkpoints and summary are every job's
(:class:`~sde_torchrl.trainers.job.Job`).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sde_torchrl.collectors.episode_queue import EpisodeQueue
from sde_torchrl.collectors.rollout import collect_episodes
from sde_torchrl.jobs.checkpoint import job_streams
from sde_torchrl.jobs.run_dir import RunDirectory, episodes_after
from sde_torchrl.objectives.estimators import EpisodicEstimator
from sde_torchrl.objectives.pgpe import PGPEEstimator
from sde_torchrl.trainers.best import BEST_POLICY_GIF, BestPolicy
from sde_torchrl.trainers.final_check import run_final_check
from sde_torchrl.trainers.guard import FiniteGuard
from sde_torchrl.trainers.job import Job
from sde_torchrl.trainers.optim import LearningRateSchedule
from sde_torchrl.trainers.report import Reporter
from sde_torchrl.trainers.settings import TrainingSettings
from sde_torchrl.trainers.summary import LoopState, exploration_state, per_step_factor, summarize
from sde_torchrl.utils.nonfinite import nonfinite_policy

log = logging.getLogger(__name__)


class Trainer(Job):
    """Trains ``runs`` independent learners side by side.

    Args:
        env: training env, batch ``[runs, episodes_per_update]``, with the explorer's primer.
        eval_env: evaluation env, batch ``[runs, eval_episodes]``.
        policy: ``TensorDictSequential(actor, explorer)`` with run-stacked parameters.
        estimator: an :class:`~sde_torchrl.objectives.estimators.EpisodicEstimator` over ``policy``, or a
            :class:`~sde_torchrl.objectives.pgpe.PGPEEstimator` (``explorer=pgpe``).
        optimizer: optimiser over the policy's parameters (``SGD(lr=α)`` is eq. 1); an
            element-wise one (SGD, momentum, Adam) keeps stacked runs independent.
        settings: the job's :class:`TrainingSettings`.
        logger: optional TorchRL logger (``log_scalar``) for run-averaged curves.
        lr_schedule: sets the optimiser's learning rate before each update (``None``: constant).
        check_env: makes the env of the job's final check, batch ``[runs, episodes]`` for the
            episodes asked, on the runs' ``final_eval`` streams (needed when ``final_episodes > 0``).

    Examples:
        See ``train.py`` and :func:`sde_torchrl.config.build.build_trainer`.
    """

    def __init__(
        self, env: EnvBase, eval_env: EnvBase, policy: TensorDictSequential,
        estimator: EpisodicEstimator | PGPEEstimator, optimizer: torch.optim.Optimizer,
        settings: TrainingSettings, logger: Any = None, lr_schedule: LearningRateSchedule | None = None,
        check_env: Callable[[int], EnvBase] | None = None,
    ) -> None:
        self.env, self.eval_env, self.policy, self.lr_schedule = env, eval_env, policy, lr_schedule
        self.check_env = check_env
        self.best = BestPolicy(policy, env.batch_size[0])
        self.estimator, self.optimizer, self.settings, self.logger = estimator, optimizer, settings, logger
        self.runs = env.batch_size[0]
        self.guard = FiniteGuard(policy, estimator, self.runs, settings.first_run)
        device = next(iter(estimator.learnable_parameters().values())).device
        #: with ``queue_scores=as_collected`` the queue holds ``{"episodes", "scores"}`` per episode
        self.keeps_scores = bool(settings.episode_queue) and settings.queue_scores == "as_collected"
        kept = ["episodes", "scores"] if self.keeps_scores else estimator.in_keys
        self.queue = EpisodeQueue(settings.episode_queue, settings.episodes_per_update, kept,
                                  device=device) if settings.episode_queue else None

    def _rollout(self, env: EnvBase) -> TensorDictBase:
        """Whole episodes on ``env`` by the fastest path that gives ``env.rollout``'s episodes
        (:func:`~sde_torchrl.collectors.rollout.collect_episodes`; ``tensor_rollout=False`` forces ``env.rollout``)."""
        with nonfinite_policy("guarded"):  # a diverged policy's NaN actions: the guard names the update
            return collect_episodes(env, self.policy, self.settings.episode_length, fast=self.settings.tensor_rollout)

    def collect(self) -> TensorDictBase:
        """``N`` fresh exploratory episodes per run, ``[runs, N, T]``."""
        return self._rollout(self.env)

    def collect_scored(self) -> TensorDictBase:
        """:meth:`collect`'s episodes with their scores under the parameters that collected
        them (the estimator's ``collected_scores``:
        :meth:`~sde_torchrl.objectives.estimators.EpisodicEstimator.collected_scores`,
        :meth:`~sde_torchrl.objectives.pgpe.PGPEEstimator.collected_scores`),
        ``{"episodes": [runs, N, T], "scores": ...}`` shaped ``[runs, N]``: what the queue keeps
        under ``queue_scores=as_collected``."""
        episodes = self.collect()
        with nonfinite_policy("guarded"):  # a non-finite score is the guard's to name, at the update
            scores = self.estimator.collected_scores(episodes)
        kept = episodes.select(*self.estimator.in_keys)
        return TensorDict({"episodes": kept, "scores": scores}, batch_size=episodes.batch_size[:-1])

    def evaluate(self) -> torch.Tensor:
        """Mean return of deterministic episodes (no exploration noise) per run, ``[runs]``, in
        the estimator's return definition, on the CPU."""
        return self.estimator.returns(self.evaluation_episodes()).mean(-1).cpu()

    def evaluation_episodes(self) -> TensorDictBase:
        """Fresh deterministic episodes (no exploration noise) on the evaluation env, ``[runs, E, T]``."""
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            return self._rollout(self.eval_env)

    def estimate(self, episodes: TensorDictBase, update: int,
                 scores: TensorDictBase | None = None) -> dict[str, torch.Tensor]:
        """One estimator pass and one optimiser step (eq. 1 with ``SGD``) at update ``update``'s
        learning rate, guarded against non-finite values; the statistics it returns (per-run
        mean return, gradient norm, exploration state) are on the CPU, whatever the device.
        ``scores``: the episodes' scores as collected (:meth:`collect_scored`); ``None``: the
        estimator scores them under the current parameters.

        The estimator runs under the non-finite policy ``"guarded"``
        (:mod:`sde_torchrl.utils.nonfinite`), as the rollouts do: its own checks step aside and
        the guard, which knows the update, reports.

        Raises:
            NonFiniteError: for a non-finite episode return, score, gradient or (after the
                step) parameter, naming the update, the runs and the parameter.
        """
        with nonfinite_policy("guarded"):
            self.guard.check_returns(update, self.estimator.returns(episodes))
            out = self.estimator(episodes) if scores is None else self.estimator(episodes, scores=scores)
            self.guard.check_estimate(update, out, episodes, scores)
        self.optimizer.zero_grad(set_to_none=True)
        out["loss_objective"].backward()
        if self.lr_schedule is not None:
            self.lr_schedule.apply(update)
        self.optimizer.step()
        self.guard.check_parameters(update)
        stats = {"return_mean": out["return_mean"], "grad_norm": out["gradient_norm"],
                 "exploration": exploration_state(self.policy, self.runs)}
        return {name: value.detach().cpu() for name, value in stats.items()}  # bookkeeping stays on the CPU

    def update(self, k: int) -> dict[str, torch.Tensor]:
        """Update ``k``: this update's episodes (fresh, or the queue renewed), one estimate and step."""
        if self.keeps_scores:
            batch = self.queue.next_batch(self.collect_scored)
            return self.estimate(batch["episodes"], k, batch["scores"])
        return self.estimate(self.queue.next_batch(self.collect) if self.queue else self.collect(), k)

    def ends_early(self, state: LoopState, stats: dict[str, torch.Tensor]) -> bool:
        """Marks the runs whose mean return exceeded ``r_lim``; with ``stop_at_threshold``, ends once all have."""
        if self.settings.r_lim is not None:
            state.reached |= stats["return_mean"] > self.settings.r_lim
        return self.settings.stop_at_threshold and bool(state.reached.all())

    def check_evaluation(self, k: int, returns: torch.Tensor) -> torch.Tensor:
        return self.guard.check_evaluation(k, returns)

    def episodes_after(self, update: int) -> int:
        """Episodes each run has collected by the end of update ``update`` (0-based)."""
        return episodes_after(update, self.settings.episodes_per_update, self.settings.episode_queue)

    def logged_step(self, updates: int) -> int:
        return self.episodes_after(updates - 1) if updates else 0

    def make_reporter(self, done: int, progress: bool) -> Reporter:
        s = self.settings
        return Reporter(self.logger, s.updates, done, self.runs * s.episodes_per_update * s.episode_length, progress,
                        per_step=per_step_factor(self.estimator.episode_return, s.episode_length))

    def checkpointed(self) -> tuple[nn.Module, dict[str, Any]]:
        return self.policy, job_streams(self.policy, self.env, self.eval_env)

    def save_extras(self, state: LoopState) -> dict[str, Any]:
        if self.queue is not None:
            state.queue = self.queue.state_dict()
        return {}

    def restore_extras(self, extras: dict[str, Any], state: LoopState) -> None:
        if self.queue is None:
            return
        s = self.settings
        episodes = [self.runs, s.episode_queue, s.episode_length]
        if self.keeps_scores:
            self.queue.load_state_dict(state.queue, episodes[:2], {"episodes": episodes, "scores.step": episodes})
        else:
            self.queue.load_state_dict(state.queue, episodes)

    def close(self) -> None:
        """Closes both envs (their simulators: 200 ball-catching worlds hold ~5.7 GB), so that a
        process running job after job (a joblib or Ray worker) does not accumulate them."""
        for env in (self.env, self.eval_env):
            env.close(raise_if_closed=False)

    def summarize(self, state: LoopState) -> dict[str, Any]:
        """The job's summary (:func:`~sde_torchrl.trainers.summary.summarize`) and its return definition."""
        return {**summarize(state, self.settings, self.policy, self.episodes_after),
                "episode_return": self.estimator.episode_return}

    def final_check(self, run_dir: RunDirectory) -> dict[str, Any]:
        """The final and the best policies on the same ``final_episodes`` fresh deterministic
        episodes per run (:func:`~sde_torchrl.trainers.final_check.run_final_check`), once the
        training and evaluation envs are closed (their simulators are done with); where the env
        can film, the best policy filmed (:meth:`film_best`)."""
        for env in (self.env, self.eval_env):
            env.close(raise_if_closed=False)
        log.info("checking the final and the best policies on %d fresh episodes per run", self.settings.final_episodes)
        with set_exploration_type(ExplorationType.DETERMINISTIC), nonfinite_policy("guarded"):
            check = run_final_check(self.check_env, self.settings.final_episodes, self.settings.eval_episodes,
                                    self.best, self._rollout, self.estimator.returns)
        self.film_best(run_dir, check)
        return check

    def film_best(self, run_dir: RunDirectory, check: dict[str, Any]) -> None:
        """Where the env can film an episode (ball catching): the run whose best policy did best
        on the fresh episodes, that policy on another fresh episode, as ``best_policy.gif``."""
        returns = [sum(run) / len(run) for run in check["best"]]
        run = max(range(len(returns)), key=returns.__getitem__)
        with self.best.loaded():
            filmed = film_policy(self.policy, self.eval_env, run, run_dir.path / BEST_POLICY_GIF,
                                 seed=self.settings.first_run + run)
        if filmed is not None:
            log.info("filmed run %d's best policy on another fresh ball (mean reward per step %.3f): %s",
                     self.settings.first_run + run, filmed, run_dir.path / BEST_POLICY_GIF)

    def first_update_notice(self, update: int) -> str:
        s = self.settings
        fill = self.queue is not None and update == 0
        episodes = s.episode_queue if fill else s.episodes_per_update
        return (f"update {update + 1} of {s.updates} still running after {self.first_update_notice_s:g} s: collecting "
                f"{episodes} episodes of {s.episode_length} steps for each of {self.runs} runs"
                f"{' (the episode queue is filled first)' if fill else ''}, then estimating the gradient")


def film_policy(policy: TensorDictSequential, env: EnvBase, run: int, path: str | os.PathLike,
                seed: int = 0) -> float | None:
    """Films run ``run`` of a (run-stacked) policy, without exploration, on one episode of
    ``env``'s task where the env can film (its ``film``: ball catching), as a GIF at ``path``.

    Returns:
        The filmed episode's return as the env gives it (ball catching: mean reward per step),
        or ``None`` where the env cannot film.
    """
    base = getattr(env, "base_env", env)
    if not hasattr(base, "film"):
        return None
    runs = env.batch_size[0]

    def act(features: torch.Tensor) -> torch.Tensor:
        shaped = features.to(torch.float32).expand(runs, 1, -1)
        return policy(TensorDict({"observation": shaped}, batch_size=[runs, 1]))["action"][run, 0]

    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        return base.film(act, path, seed=seed)
