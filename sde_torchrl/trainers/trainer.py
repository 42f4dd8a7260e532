"""The training loop: collect whole episodes, estimate, update, evaluate.

Every update collects ``N`` fresh episodes per run (a TensorDict ``[runs, N, T]``; or renews the
episode queue, :mod:`sde_torchrl.collectors.episode_queue`), turns them into one gradient per run with an
episodic estimator and takes one optimiser step: with ``SGD(lr=α)``, the paper's plain
gradient ascent ``θ ← θ + α g`` (eq. 1); momentum, Adam and a decaying rate are options
(:mod:`sde_torchrl.trainers.optim`). Every
``eval_period`` updates (and after the last) each run's policy is evaluated without
exploration. What is around the loop has a module of its own: the non-finite guard
(:mod:`~sde_torchrl.trainers.guard`), the run directory (:mod:`~sde_torchrl.jobs.run_dir`), checkpoints
(:mod:`~sde_torchrl.jobs.checkpoint`), the summary (:mod:`~sde_torchrl.trainers.summary`), reporting
(:mod:`~sde_torchrl.trainers.report`) and stop signals (:mod:`~sde_torchrl.trainers.interrupt`).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictSequential
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sde_torchrl.collectors.episode_queue import EpisodeQueue
from sde_torchrl.collectors.rollout import collect_episodes
from sde_torchrl.jobs.checkpoint import job_streams, restore_job, result_config, save_job
from sde_torchrl.jobs.metrics import MetricRow, metric_rows, recorded_rows, update_statistics
from sde_torchrl.jobs.run_dir import FinishedRun, RunDirectory, episodes_after
from sde_torchrl.objectives.estimators import EpisodicEstimator
from sde_torchrl.objectives.pgpe import PGPEEstimator
from sde_torchrl.trainers.best import BEST_POLICY, BEST_POLICY_GIF, BestPolicy, write_best_policy
from sde_torchrl.trainers.final_check import run_final_check
from sde_torchrl.trainers.guard import FiniteGuard
from sde_torchrl.trainers.interrupt import DeferredInterrupt
from sde_torchrl.trainers.optim import LearningRateSchedule
from sde_torchrl.trainers.report import Reporter, close_logger
from sde_torchrl.trainers.settings import TrainingSettings
from sde_torchrl.trainers.summary import (
    LoopState,
    best_and_checked,
    exploration_state,
    final_levels,
    per_step_factor,
    summarize,
)
from sde_torchrl.utils.nonfinite import nonfinite_policy

log = logging.getLogger(__name__)
#: A session whose first update takes longer than this says what it is doing (a job is silent
#: until its first update ends: a large one would otherwise say nothing for minutes).
FIRST_UPDATE_NOTICE_S = 10.0


class Trainer:
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

    def update(self, episodes: TensorDictBase, update: int,
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

    def episodes_after(self, update: int) -> int:
        """Episodes each run has collected by the end of update ``update`` (0-based)."""
        return episodes_after(update, self.settings.episodes_per_update, self.settings.episode_queue)

    def close(self) -> None:
        """Closes both envs (their simulators: 200 ball-catching worlds hold ~5.7 GB), so that a
        process running job after job (a joblib or Ray worker) does not accumulate them."""
        for env in (self.env, self.eval_env):
            env.close(raise_if_closed=False)

    def train(
        self, out_dir: str | os.PathLike, labels: dict[str, Any] | None = None, *,
        checkpoint_period: int = 0, progress: bool = False,
    ) -> dict[str, Any]:
        """Runs the job (or resumes it) and writes ``metrics.csv``, ``checkpoint.pt``,
        ``summary.json``.

        The job holds ``out_dir`` (:meth:`RunDirectory.lock`) until it returns. If ``out_dir``
        holds a checkpoint, the job resumes from it: ``metrics.csv`` is checked against it, cut
        back to the checkpointed update and continued, and every random stream continues where
        it was, so the outputs equal those of an uninterrupted job. A finished job is final
        (:meth:`RunDirectory.check_job`): with or without its checkpoint, if its files agree
        nothing is changed and its summary is returned; a finished checkpoint whose summary is
        missing or disagrees with it only rewrites the summary, once ``metrics.csv`` is checked.

        Args:
            out_dir: the run directory (Hydra's output directory in ``train.py``).
            labels: entries that head ``summary.json`` (config choices, seed, the config); its
                ``config``, the job's resolved config, is the job's identity: the run directory
                records it and refuses a job of another config
                (:meth:`~sde_torchrl.jobs.run_dir.RunDirectory.check_job`; the keys outside
                :data:`~sde_torchrl.jobs.checkpoint.NON_RESULT_KEYS` count). Without it nothing is checked.
            checkpoint_period: also checkpoint every this many updates (0: only at the end and
                on Ctrl-C).
            progress: show a progress bar (:mod:`sde_torchrl.trainers.progress`).

        Returns:
            The summary (also written to ``summary.json``).

        Raises:
            NonFiniteError: a non-finite value; ``metrics.csv`` keeps the updates before it.
            TrainingInterrupted: on Ctrl-C, SIGTERM or SIGUSR2, after saving a checkpoint
                (:mod:`~sde_torchrl.trainers.interrupt`).
            CheckpointMismatchError: ``out_dir`` holds another job's checkpoint, or another
                config's finished job.
            RunDirectoryInUse: another process holds ``out_dir`` (nothing is changed).
            DamagedFileError: ``checkpoint.pt`` or ``metrics.csv`` is damaged (nothing is resumed),
                or the files of a finished job without a checkpoint disagree
                (:class:`~sde_torchrl.jobs.run_dir.UnfinishedRunError`; nothing is changed).
        """
        return train_in_directory(self, out_dir, labels, checkpoint_period, progress)

    def _summary(self, state: LoopState) -> dict[str, Any]:
        """The job's summary (:func:`~sde_torchrl.trainers.summary.summarize`) and its return definition."""
        return {**summarize(state, self.settings, self.policy, self.episodes_after),
                "episode_return": self.estimator.episode_return}

    def _loop(self, run_dir: RunDirectory, state: LoopState, period: int, progress: bool) -> None:
        """Updates from ``state.update`` to the end: collect, estimate and step, evaluate, record."""
        s = self.settings
        session_start, session_wall = time.perf_counter(), state.wall_s
        reporter = Reporter(self.logger, s.updates, state.update,
                            self.runs * s.episodes_per_update * s.episode_length, progress,
                            per_step=per_step_factor(self.estimator.episode_return, s.episode_length))
        notice = threading.Timer(FIRST_UPDATE_NOTICE_S, log.info, [self._first_update_notice(state.update)])
        notice.daemon = True
        with run_dir.open_metrics(self._recorded_rows(state)) as metrics, DeferredInterrupt() as interrupt:
            notice.start()
            try:
                for k in range(state.update, s.updates):
                    if self.keeps_scores:
                        batch = self.queue.next_batch(self.collect_scored)
                        stats = self.update(batch["episodes"], k, batch["scores"])
                    else:
                        stats = self.update(self.queue.next_batch(self.collect) if self.queue else self.collect(), k)
                    notice.cancel()
                    state.add(stats)
                    if s.r_lim is not None:
                        state.reached |= stats["return_mean"] > s.r_lim
                    is_last = k == s.updates - 1 or (s.stop_at_threshold and bool(state.reached.all()))
                    eval_return = None
                    if is_last or (s.eval_period and (k + 1) % s.eval_period == 0):
                        eval_return = state.evals[k] = self.guard.check_evaluation(k, self.evaluate())
                        self.best.observe(k, eval_return)
                    statistics = update_statistics(s.first_run, k, self.episodes_after(k), stats, eval_return)
                    metrics.write(metric_rows(statistics))
                    state.update, state.finished = k + 1, is_last
                    state.wall_s = session_wall + time.perf_counter() - session_start
                    reporter.update(k, self.episodes_after(k), statistics)
                    if is_last:
                        break
                    if interrupt.requested or (period and state.update % period == 0):
                        metrics.sync()
                        self._save(run_dir, state)
                    if interrupt.requested:
                        interrupt.stop(state.update, run_dir.path)
            finally:
                notice.cancel()
                reporter.close()
            metrics.sync()
            if s.final_episodes and state.finished:
                state.final_check = self._final_check()
                self._film_best(run_dir, state.final_check)
        self._save(run_dir, state)

    def _final_check(self) -> dict[str, Any]:
        """The final and the best policies on the same ``final_episodes`` fresh deterministic
        episodes per run (:func:`~sde_torchrl.trainers.final_check.run_final_check`); the
        training and evaluation envs are closed first (their simulators are done with)."""
        for env in (self.env, self.eval_env):
            env.close(raise_if_closed=False)
        log.info("checking the final and the best policies on %d fresh episodes per run", self.settings.final_episodes)
        with set_exploration_type(ExplorationType.DETERMINISTIC), nonfinite_policy("guarded"):
            return run_final_check(self.check_env, self.settings.final_episodes, self.settings.eval_episodes,
                                   self.best, self._check_rollout, self.estimator.returns)

    def _film_best(self, run_dir: RunDirectory, check: dict[str, Any]) -> None:
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

    def _check_rollout(self, env: EnvBase) -> TensorDictBase:
        return collect_episodes(env, self.policy, self.settings.episode_length, fast=self.settings.tensor_rollout)

    def _first_update_notice(self, update: int) -> str:
        """What the session's first update does, for a job that has been silent for a while."""
        s = self.settings
        fill = self.queue is not None and update == 0
        episodes = s.episode_queue if fill else s.episodes_per_update
        return (f"update {update + 1} of {s.updates} still running after {FIRST_UPDATE_NOTICE_S:g} s: collecting "
                f"{episodes} episodes of {s.episode_length} steps for each of {self.runs} runs"
                f"{' (the episode queue is filled first)' if fill else ''}, then estimating the gradient")

    def _recorded_rows(self, state: LoopState) -> list[MetricRow]:
        """The ``metrics.csv`` rows of the updates ``state`` holds (what a checkpoint recorded)."""
        return recorded_rows(state.record(), self.settings.first_run, self.episodes_after)

    def _save(self, run_dir: RunDirectory, state: LoopState) -> None:
        if self.queue is not None:
            state.queue = self.queue.state_dict()
        state.best = self.best.state_dict()
        save_job(run_dir.checkpoint, config=run_dir.config, loop=state.state_dict(), policy=self.policy,
                 optimizer=self.optimizer, streams=job_streams(self.policy, self.env, self.eval_env))

    def _resume(self, run_dir: RunDirectory) -> LoopState:
        """A fresh :class:`LoopState`, or the checkpointed one with everything restored."""
        if not run_dir.has_checkpoint():
            run_dir.start_new_job()
            return LoopState(update=0, reached=torch.zeros(self.runs, dtype=torch.bool))
        loop = restore_job(run_dir.checkpoint, policy=self.policy, optimizer=self.optimizer,
                           streams=job_streams(self.policy, self.env, self.eval_env), updates=self.settings.updates)
        state = LoopState.from_state_dict(loop)
        run_dir.check_metrics(self._recorded_rows(state), state.finished)
        if state.best is not None:
            self.best.load_state_dict(state.best)
        if not state.finished:  # an earlier session's summary (a checkpoint replaced by an older one)
            run_dir.summary.unlink(missing_ok=True)
        if self.queue is not None:
            s = self.settings
            episodes = [self.runs, s.episode_queue, s.episode_length]
            if self.keeps_scores:
                self.queue.load_state_dict(state.queue, episodes[:2], {"episodes": episodes, "scores.step": episodes})
            else:
                self.queue.load_state_dict(state.queue, episodes)
        run_dir.clear_error()
        if not state.finished:
            run_dir.truncate_logger_csv(self.episodes_after(state.update - 1) if state.update else 0)
            log.info("resuming %s after update %d of %d", run_dir.path, state.update, self.settings.updates)
        else:
            log.info("%s holds a finished job whose summary.json is missing or disagrees with its checkpoint: "
                     "rewritten from it", run_dir.path)
        return state


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


def train_in_directory(
    trainer: Any, out_dir: str | os.PathLike, labels: dict[str, Any] | None, checkpoint_period: int,
    progress: bool,
) -> dict[str, Any]:
    """A trainer's job in its run directory, the one way every trainer runs (:meth:`Trainer.train`
    says what it guarantees): the directory held and checked to hold this job (the one check,
    :meth:`~sde_torchrl.jobs.run_dir.RunDirectory.check_job`), a finished job left as it is, a
    checkpoint resumed, the loop run, the logger closed, the summary written.

    Args:
        trainer: has ``_resume(run_dir)``, ``_loop(run_dir, state, period, progress)``,
            ``_summary(state)`` and ``logger``; what it records of the job's config it reads off
            the run directory (``run_dir.config``).
        out_dir, labels, checkpoint_period, progress: as :meth:`Trainer.train` takes them.

    Returns:
        The summary (also written to ``summary.json``).
    """
    run_dir = RunDirectory(out_dir, result_config((labels or {}).get("config")))
    with run_dir.lock():
        done = run_dir.check_job()
        if done is not None:
            log.info("%s", finished_line(done))
            return done.summary
        state = trainer._resume(run_dir)
        try:
            if not state.finished:
                trainer._loop(run_dir, state, checkpoint_period, progress)
        finally:
            close_logger(trainer.logger)
        if state.best is not None:
            write_best_policy(run_dir.path / BEST_POLICY, state.best)
        summary = {**(labels or {}), **trainer._summary(state), **best_and_checked(state)}
        summary = run_dir.write_summary({**summary, **final_levels(summary, state)})
    log.info("results in %s", run_dir.path.resolve())
    return summary


def finished_line(job: FinishedRun) -> str:
    """The one line that reports a finished job found in its directory, and the choices left.

    Examples:
        >>> from pathlib import Path
        >>> finished_line(FinishedRun(Path("runs/a"), {"runs": 2, "updates_done": 12}, []))  # doctest: +ELLIPSIS
        'runs/a holds a finished job (12 updates of 2 runs): nothing was changed; a finished job is final: ...'
    """
    return (f"{job.path} holds a finished job ({job.summary['updates_done']} updates of {job.summary['runs']} runs): "
            "nothing was changed; a finished job is final: to train with other settings (more updates, say), give "
            "the job another directory; to train this one again from the start, remove its directory first")
