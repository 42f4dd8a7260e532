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
import signal
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sde_torchrl.checkpoint import (
    CHECKPOINT, FORMAT as CHECKPOINT_FORMAT, CheckpointMismatchError, config_differences, env_streams,
    global_random_state, load_checkpoint, module_streams, replace_atomically, result_config,
    save_checkpoint, set_global_random_state, tmp_path,
)
from sde_torchrl.estimators import EpisodicEstimator, episode_returns, episode_scores
from sde_torchrl.progress import Progress, RateMeter
from sde_torchrl.rng import RunStreams
from sde_torchrl.rollout import linear_episode_env, linear_episode_rollout, tensor_rollout, tensor_step_env

log = logging.getLogger(__name__)

METRIC_FIELDS = ("run", "update", "episodes", "return_mean", "eval_return", "grad_norm")


class NonFiniteError(RuntimeError):
    """A return, score, gradient or parameter became NaN or infinite.

    Attributes:
        update: index of the update (0-based) where it happened.
        what: ``"return"``, ``"score"``, ``"gradient"`` or ``"parameter"``.
        parameter: the parameter's name in the policy's state dict, or ``None``.
        runs: global indices of the runs concerned.
    """

    def __init__(self, update: int, what: str, runs: list[int], parameter: str | None = None,
                 values: torch.Tensor | None = None, detail: str = "") -> None:
        self.update, self.what, self.runs, self.parameter = update, what, runs, parameter
        subject = what if parameter is None else (
            f"parameter {parameter}" if what == "parameter" else f"{what} of parameter {parameter}")
        shown = "" if values is None else f" {values.detach().flatten()[:6].tolist()}"
        super().__init__(
            f"non-finite {subject} at update {update} in run{'s' if len(runs) != 1 else ''} "
            f"{', '.join(map(str, runs))}:{shown}{detail}; metrics.csv keeps the updates before it "
            "(lower lr or set estimator.max_grad_norm)"
        )


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C during training: a checkpoint was saved after the last finished update."""

    def __init__(self, updates_done: int, out_dir: Path) -> None:
        self.updates_done, self.out_dir = updates_done, out_dir
        super().__init__(f"interrupted after update {updates_done}; checkpoint saved in {out_dir}")


@dataclass
class LoopState:
    """What the summary is computed from, and where the loop stands (checkpointed).

    Attributes:
        update: updates done.
        reached: per run, whether an update's mean return exceeded ``r_lim``.
        returns: per update, the mean exploratory return of each run ``[runs]``.
        evals: update index → mean deterministic return of each run ``[runs]``.
        wall_s: training time of earlier sessions of this job (resumed jobs).
        finished: the job ran to its end.
        queue: with an episode queue, its episodes ``[runs, Q, T]`` as a nested dict of tensors.
    """

    update: int
    reached: torch.Tensor
    returns: list[torch.Tensor] = field(default_factory=list)
    evals: dict[int, torch.Tensor] = field(default_factory=dict)
    wall_s: float = 0.0
    finished: bool = False
    queue: dict[str, Any] | None = None

    def state_dict(self) -> dict[str, Any]:
        return {"update": self.update, "reached": self.reached.clone(),
                "returns": [r.clone() for r in self.returns],
                "evals": {k: v.clone() for k, v in self.evals.items()},
                "wall_s": self.wall_s, "finished": self.finished, "queue": self.queue}

    @classmethod
    def from_state_dict(cls, state: dict[str, Any]) -> LoopState:
        return cls(**state)


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
        episode_queue: 0 for fresh episodes at every update; ``Q > 0`` for the paper's
            ball-catching schedule: each update uses the last ``Q`` episodes of each run,
            filled at the start by ``Q / N`` collections, then renewed by ``N`` new
            episodes after every update (``Q`` must be a multiple of ``N``).
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
    episode_queue: int = 0

    def __post_init__(self) -> None:
        for name in ("updates", "episodes_per_update", "episode_length", "eval_episodes"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if not isinstance(self.eval_period, int) or self.eval_period < 0:
            raise ValueError(f"eval_period must be a non-negative integer, got {self.eval_period!r}")
        if self.episode_queue < 0 or self.episode_queue % self.episodes_per_update:
            raise ValueError(f"episode_queue must be 0 or a multiple of episodes_per_update "
                             f"({self.episodes_per_update}), got {self.episode_queue}")
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
        """Fresh whole episodes on ``env``: where the env and policy allow, a world at a time
        under its episode's linear map (:func:`linear_episode_rollout`) or by tensor stepping
        (:func:`tensor_rollout`); both give ``env.rollout``'s episodes at a fraction of its
        overhead. Else by ``env.rollout``."""
        steps = self.settings.episode_length
        with torch.no_grad():
            if self.settings.tensor_rollout:
                if (base := linear_episode_env(env, self.policy)) is not None:
                    return linear_episode_rollout(base, self.policy, steps)
                if (base := tensor_step_env(env, self.policy)) is not None:
                    return tensor_rollout(base, self.policy, steps)
            return env.rollout(steps, self.policy, break_when_any_done=False)

    def collect(self) -> Any:
        """``N`` fresh exploratory episodes per run, ``[runs, N, T]``."""
        return self._rollout(self.env)

    def evaluate(self) -> torch.Tensor:
        """Mean return of deterministic episodes (no exploration noise) per run, ``[runs]``."""
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            episodes = self._rollout(self.eval_env)
        return episode_returns(episodes).mean(-1)

    def update(self, episodes: Any, update: int) -> dict[str, torch.Tensor]:
        """One estimator pass and one optimiser step.

        Raises:
            NonFiniteError: for a non-finite episode return, score, gradient or (after the
                step) parameter, naming the update, the runs and the parameter.
        """
        self._check_finite(update, "return", episode_returns(episodes))
        out = self.estimator(episodes)
        if not bool(torch.isfinite(out["score_norm"]).all()):
            self._raise_named(update, "score", episode_scores(self.estimator.log_likelihood, episodes),
                              out["score_norm"])
        if not bool(torch.isfinite(out["gradient"]).all()):
            self._raise_named(update, "gradient", self._split(out["gradient"]))
        self.optimizer.zero_grad(set_to_none=True)
        out["loss_objective"].backward()
        self.optimizer.step()
        params = self.estimator.learnable_parameters()
        if not all(bool(torch.isfinite(p).all()) for p in params.values()):
            self._raise_named(update, "parameter", {n: p.detach() for n, p in params.items()})
        return {"return_mean": out["return_mean"], "grad_norm": out["gradient_norm"]}

    def _split(self, flat: torch.Tensor) -> dict[str, torch.Tensor]:
        """A flat per-run vector ``[runs, K]`` cut into the learnable parameters' pieces."""
        sizes = [p[0].numel() if p.dim() and p.shape[0] == self.runs else p.numel()
                 for p in self.estimator.learnable_parameters().values()]
        return dict(zip(self.estimator.learnable_parameters(), flat.split(sizes, dim=-1)))

    def _bad_runs(self, value: torch.Tensor) -> list[int]:
        """Global indices of the runs whose slice of ``value`` (runs first) is not finite."""
        if value.dim() == 0 or value.shape[0] != self.runs:
            return [self.settings.first_run + r for r in range(self.runs)]
        bad = ~torch.isfinite(value.reshape(self.runs, -1)).all(-1)
        return [self.settings.first_run + int(r) for r in bad.nonzero().flatten()]

    def _check_finite(self, update: int, what: str, value: torch.Tensor) -> None:
        if not bool(torch.isfinite(value).all()):
            name, largest = self._largest_parameter()
            raise NonFiniteError(update, what, self._bad_runs(value), values=value,
                                 detail=f"; largest parameter entry: {name} = {largest:.3g}")

    def _largest_parameter(self) -> tuple[str, float]:
        """The policy parameter entry of largest magnitude (what usually made returns blow up)."""
        name, param = max(self.policy.named_parameters(), key=lambda kv: float(kv[1].detach().abs().max()))
        flat = param.detach().flatten()
        return name, float(flat[flat.abs().argmax()])

    def _raise_named(
        self, update: int, what: str, values: dict[str, torch.Tensor], norm: torch.Tensor | None = None,
    ) -> None:
        """Raises for the first non-finite entry of ``values`` (estimator names → tensors),
        naming the parameter as in the policy's state dict. If every entry is finite, their
        per-run ``norm`` overflowed: the runs whose norm is not finite are named."""
        policy_names = self._policy_names()
        for name, value in values.items():
            if not bool(torch.isfinite(value).all()):
                raise NonFiniteError(update, what, self._bad_runs(value), policy_names.get(name, name), value)
        overflow = torch.full((self.runs,), float("nan")) if norm is None else norm
        raise NonFiniteError(update, f"{what} norm", self._bad_runs(overflow), values=overflow,
                             detail=" (finite entries too large to square in float32)")

    def _policy_names(self) -> dict[str, str]:
        """Estimator parameter names → the policy's (``module.0.module.weight``)."""
        by_id = {id(p): n for n, p in self.policy.named_parameters()}
        return {n: by_id.get(id(p), n) for n, p in self.estimator.learnable_parameters().items()}

    def close(self) -> None:
        """Closes both envs (their simulators: 200 ball-catching worlds hold ~5.7 GB), so that a
        process running job after job (a joblib or Ray worker) does not accumulate them."""
        for env in (self.env, self.eval_env):
            env.close(raise_if_closed=False)

    def train(
        self, out_dir: str | os.PathLike, labels: dict[str, Any] | None = None, *,
        config: dict[str, Any] | None = None, checkpoint_period: int = 0, progress: bool = False,
    ) -> dict[str, Any]:
        """Runs the job (or resumes it) and writes ``metrics.csv``, ``checkpoint.pt``,
        ``summary.json``.

        If ``out_dir`` holds a checkpoint, the job resumes from it: ``metrics.csv`` is cut back
        to the checkpointed update and continued, and every random stream continues where it
        was, so the outputs equal those of an uninterrupted job. A checkpoint of a finished job
        only (re)writes the summary.

        Args:
            out_dir: the run directory (Hydra's output directory in ``train.py``).
            labels: entries that head ``summary.json`` (config choices, seed, the config).
            config: the job's resolved config, stored in the checkpoint; a checkpoint written
                under a config that differs (outside :data:`~sde_torchrl.checkpoint.NON_RESULT_KEYS`)
                is refused. ``None`` skips the check.
            checkpoint_period: also checkpoint every this many updates (0: only at the end and
                on Ctrl-C).
            progress: show a progress bar (:mod:`sde_torchrl.progress`).

        Returns:
            The summary (also written to ``summary.json``).

        Raises:
            NonFiniteError: a non-finite value; ``metrics.csv`` keeps the updates before it.
            TrainingInterrupted: on Ctrl-C, after saving a checkpoint.
            CheckpointMismatchError: ``out_dir`` holds another job's checkpoint.
        """
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        config = result_config(config)
        state = self._resume(out, config)
        try:
            if not state.finished:
                self._loop(out, state, config, checkpoint_period, progress)
        finally:
            close_logger(self.logger)
        summary = {**(labels or {}), **self._summary(state)}
        write_json_atomic(out / "summary.json", summary)
        log.info("results in %s", out.resolve())
        return summary

    def _loop(self, out: Path, state: LoopState, config: dict | None, period: int, progress: bool) -> None:
        """Updates from ``state.update`` to the end, checkpointing on the way."""
        s = self.settings
        session_start, session_wall = time.perf_counter(), state.wall_s
        bar = Progress(s.updates, state.update, enabled=progress)
        rate = RateMeter()
        steps_per_update = self.runs * s.episodes_per_update * s.episode_length
        with MetricsFile(out / "metrics.csv", keep_rows=state.update * self.runs) as metrics, \
                _DeferredInterrupt() as interrupt:
            try:
                for k in range(state.update, s.updates):
                    stats = self.update(self._batch(state), k)
                    state.returns.append(stats["return_mean"])
                    if s.r_lim is not None:
                        state.reached |= stats["return_mean"] > s.r_lim
                    is_last = k == s.updates - 1 or (s.stop_at_threshold and bool(state.reached.all()))
                    eval_return = None
                    if is_last or (s.eval_period and (k + 1) % s.eval_period == 0):
                        eval_return = self.evaluate()
                        state.evals[k] = eval_return
                    metrics.write(self._rows(k, stats, eval_return))
                    state.update, state.finished = k + 1, is_last
                    state.wall_s = session_wall + time.perf_counter() - session_start
                    speed = rate.add(steps_per_update)
                    self._log(k, stats, eval_return, speed)
                    bar.step(float(stats["return_mean"].mean()), speed)
                    if is_last:
                        break
                    if interrupt.requested:
                        metrics.sync()
                        self._save(out, state, config)
                        raise TrainingInterrupted(state.update, out)
                    if period and state.update % period == 0:
                        metrics.sync()
                        self._save(out, state, config)
            finally:
                bar.close()
            metrics.sync()
        self._save(out, state, config)

    def _batch(self, state: LoopState) -> Any:
        """The episodes of the next update: fresh ones, or the renewed episode queue."""
        s = self.settings
        if not s.episode_queue:
            return self.collect()
        if state.queue is None:
            fill = [self.collect() for _ in range(s.episode_queue // s.episodes_per_update)]
            queue = torch.cat([self._queued(e) for e in fill], dim=1)
        else:
            old = TensorDict(state.queue, batch_size=[self.runs, s.episode_queue, s.episode_length])
            queue = torch.cat([old[:, s.episodes_per_update:], self._queued(self.collect())], dim=1)
        state.queue = queue.to_dict()
        return queue

    def _queued(self, episodes: Any) -> Any:
        """Only what the estimator reads: the queue is checkpointed."""
        return episodes.select(*self.estimator.log_likelihood.in_keys, self.estimator.tensor_keys.reward)

    def episodes_after(self, update: int) -> int:
        """Episodes each run has collected by the end of update ``update`` (0-based)."""
        s = self.settings
        return (update + 1) * s.episodes_per_update + max(s.episode_queue - s.episodes_per_update, 0)

    def _rows(self, k: int, stats: dict, eval_return: torch.Tensor | None) -> list[dict[str, Any]]:
        s = self.settings
        return [{
            "run": s.first_run + r, "update": k, "episodes": self.episodes_after(k),
            "return_mean": float(stats["return_mean"][r]),
            "eval_return": "" if eval_return is None else float(eval_return[r]),
            "grad_norm": float(stats["grad_norm"][r]),
        } for r in range(self.runs)]

    # ------------------------------------------------------------------ checkpoint and resume

    def _streams(self) -> dict[str, RunStreams | None]:
        explorer = module_streams(self.policy)
        return {"explorer": explorer[0] if explorer else None,
                "env": env_streams(self.env), "eval_env": env_streams(self.eval_env)}

    def _save(self, out: Path, state: LoopState, config: dict | None) -> None:
        """Everything :meth:`_resume` needs to continue bit for bit (see :mod:`sde_torchrl.checkpoint`)."""
        save_checkpoint(out / CHECKPOINT, {
            "format": CHECKPOINT_FORMAT,
            "config": config,
            "updates": state.update,
            "policy": self.policy.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "streams": {k: None if v is None else v.state_dict() for k, v in self._streams().items()},
            "random": global_random_state(),
            "loop": state.state_dict(),
        })

    def _resume(self, out: Path, config: dict | None) -> LoopState:
        """A fresh :class:`LoopState`, or the checkpointed one with everything restored."""
        path = out / CHECKPOINT
        if not path.exists():
            for stale in ("metrics.csv", "summary.json", "error.txt"):
                (out / stale).unlink(missing_ok=True)
            return LoopState(update=0, reached=torch.zeros(self.runs, dtype=torch.bool))
        saved = load_checkpoint(path)
        if config is not None and saved.get("config") is not None:
            diff = config_differences(saved["config"], config)
            if diff:
                raise CheckpointMismatchError(
                    f"{path} was written by another config ({'; '.join(diff[:5])}); resume with the "
                    "same overrides, or choose a new hydra.run.dir (or delete the checkpoint)"
                )
        self.policy.load_state_dict(saved["policy"])
        self.optimizer.load_state_dict(saved["optimizer"])
        for name, streams in self._streams().items():
            if saved["streams"].get(name) is not None:
                if streams is None:
                    raise CheckpointMismatchError(f"{path} holds {name} streams this job does not have")
                streams.load_state_dict(saved["streams"][name])
            elif streams is not None:
                log.warning("checkpoint has no %s streams: the resumed job is not bitwise reproducible", name)
        set_global_random_state(saved["random"])
        state = LoopState.from_state_dict(saved["loop"])
        (out / "error.txt").unlink(missing_ok=True)
        if not state.finished:
            truncate_logger_csv(out, self.episodes_after(state.update - 1) if state.update else 0)
        log.info("resuming %s after update %d of %d", out, state.update, self.settings.updates)
        return state

    def _log(self, update: int, stats: dict, eval_return: torch.Tensor | None, speed: float) -> None:
        step = self.episodes_after(update)
        if self.logger is not None:
            self.logger.log_scalar("return_mean", float(stats["return_mean"].mean()), step=step)
            if eval_return is not None:
                self.logger.log_scalar("eval_return", float(eval_return.mean()), step=step)
        if eval_return is not None:
            log.info("update %d/%d  return %.3f  eval %.3f  %.0f env steps/s", update + 1,
                     self.settings.updates, float(stats["return_mean"].mean()),
                     float(eval_return.mean()), speed)

    def _summary(self, state: LoopState) -> dict[str, Any]:
        s = self.settings
        returns = torch.stack(state.returns)  # [updates, runs]
        above = returns > s.r_lim if s.r_lim is not None else torch.zeros_like(returns, dtype=torch.bool)
        first = [int(above[:, r].nonzero()[0]) if bool(above[:, r].any()) else None for r in range(self.runs)]
        updates_done = len(state.returns)
        final_eval = state.evals[updates_done - 1]
        return {
            "runs": self.runs,
            "first_run": s.first_run,
            "settings": asdict(s),
            "updates_done": updates_done,
            "initial_return": returns[0].tolist(),
            "final_return": returns[-1].tolist(),
            "final_eval_return": final_eval.tolist(),
            "episodes_to_threshold": [None if i is None else self.episodes_after(i) for i in first],
            "final_parameters": {  # named as in checkpoint.pt's policy state dict
                name: p.detach().reshape(self.runs, -1).tolist()
                for name, p in self.policy.named_parameters()
            },
            "env_steps": self.episodes_after(updates_done - 1) * s.episode_length * self.runs,
            "wall_s": state.wall_s,
        }


class MetricsFile:
    """``metrics.csv``, opened to continue after its first ``keep_rows`` data rows.

    Rows are flushed as they are written (a crash keeps every finished update); rows beyond
    ``keep_rows`` (written after the checkpoint a job resumes from) are dropped first, by
    rewriting the kept lines byte for byte to a temporary file renamed over the old one.

    Args:
        path: the CSV file.
        keep_rows: data rows to keep from an existing file (0 starts a new file).
    """

    def __init__(self, path: Path, keep_rows: int = 0) -> None:
        self.path, self.keep_rows = path, keep_rows
        self._file: Any = None
        self._writer: csv.DictWriter | None = None

    def __enter__(self) -> MetricsFile:
        if self.keep_rows:
            self._cut()
            self._file = open(self.path, "a", newline="")
            self._writer = csv.DictWriter(self._file, fieldnames=METRIC_FIELDS)
        else:
            self._file = open(self.path, "w", newline="")
            self._writer = csv.DictWriter(self._file, fieldnames=METRIC_FIELDS)
            self._writer.writeheader()
        return self

    def _cut(self) -> None:
        lines = self.path.read_bytes().splitlines(keepends=True) if self.path.exists() else []
        kept = lines[: 1 + self.keep_rows]
        if len(kept) < 1 + self.keep_rows or not all(line.endswith(b"\n") for line in kept):
            raise CheckpointMismatchError(
                f"{self.path} holds fewer rows ({max(len(lines) - 1, 0)}) than the checkpoint "
                f"needs ({self.keep_rows}); delete the checkpoint to start over"
            )
        tmp = tmp_path(self.path)
        with open(tmp, "wb") as f:
            f.writelines(kept)
            f.flush()
            os.fsync(f.fileno())
        replace_atomically(tmp, self.path)

    def write(self, rows: list[dict[str, Any]]) -> None:
        """Appends rows and flushes them to the OS."""
        self._writer.writerows(rows)
        self._file.flush()

    def sync(self) -> None:
        """Makes the rows written so far durable (before a checkpoint refers to them)."""
        self._file.flush()
        os.fsync(self._file.fileno())

    def __exit__(self, *exc: Any) -> None:
        self._file.close()


def close_logger(logger: Any) -> None:
    """Flushes and closes a TorchRL logger's backend (ends a wandb run, closes event files)."""
    experiment = getattr(logger, "experiment", None)
    for method in ("finish", "close"):  # wandb runs finish; tensorboard writers close
        if callable(getattr(experiment, method, None)):
            getattr(experiment, method)()
            return


def truncate_logger_csv(out: Path, max_step: int) -> None:
    """Drops the TorchRL CSV logger's rows logged after ``max_step`` (a resumed job logs them again)."""
    for path in out.glob("*/scalars/*.csv"):
        lines = path.read_bytes().splitlines(keepends=True)
        kept = [line for line in lines if line.endswith(b"\n") and _step_of(line) <= max_step]
        if len(kept) != len(lines):
            tmp = tmp_path(path)
            tmp.write_bytes(b"".join(kept))
            replace_atomically(tmp, path)


def _step_of(line: bytes) -> float:
    try:
        return float(line.split(b",", 1)[0])
    except ValueError:
        return float("inf")


class _DeferredInterrupt:
    """Turns the first Ctrl-C into a request the loop honours after the current update;
    a second Ctrl-C interrupts at once. A no-op outside the main thread."""

    def __init__(self) -> None:
        self.requested = False
        self._previous: Any = None

    def _handle(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        log.warning("Ctrl-C: saving a checkpoint after this update (Ctrl-C again to abort now)")

    def __enter__(self) -> _DeferredInterrupt:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)


def write_json_atomic(path: str | os.PathLike, data: dict) -> None:
    """Writes JSON to a temporary file and renames it: readers see all of it or nothing."""
    path = Path(path)
    tmp = tmp_path(path)
    with open(tmp, "w") as f:
        json.dump(data, f, indent=2)
        f.flush()
        os.fsync(f.fileno())
    replace_atomically(tmp, path)
