"""What one training job does: the settings the training loop reads."""

from __future__ import annotations

from dataclasses import dataclass

from sde_torchrl.utils.checks import (
    ArgumentError,
    is_finite_number,
    multiple_of,
    non_negative_int,
    one_of,
    positive_int,
)
from sde_torchrl.utils.options import QUEUE_SCORES


@dataclass(frozen=True)
class TrainingSettings:
    """What one training job does: the one home of these fields' rules (the config's
    :class:`~sde_torchrl.config.schemas.train.TrainConf` has them checked here).

    Attributes:
        updates: number of policy updates.
        episodes_per_update: ``N``, fresh episodes per run feeding one update.
        episode_length: ``T``, steps per episode.
        eval_period: evaluate every this many updates (and after the last); 0 disables
            intermediate evaluation.
        eval_episodes: deterministic episodes per evaluation and run.
        final_episodes: fresh deterministic episodes per run on which the final and the best
            policy are evaluated at the job's end (0: none).
        r_lim: convergence threshold: a run has converged at the first update whose mean
            exploratory return exceeds it (``None``: not tracked).
        first_run: global index of the first run (for labelling shards of a sweep).
        stop_at_threshold: end the job once every run has exceeded ``r_lim`` (convergence
            sweeps need nothing after that).
        tensor_rollout: collect by tensor stepping where the env supports it
            (:mod:`sde_torchrl.collectors.rollout`); ``False`` forces TorchRL's ``env.rollout``.
        episode_queue: 0 for fresh episodes at every update; ``Q > 0`` for the paper's
            ball-catching schedule: each update uses the last ``Q`` episodes of each run,
            filled at the start by ``Q / N`` collections, then renewed by ``N`` new
            episodes after every update (``Q`` must be a multiple of ``N``).
        queue_scores: with a queue, ``rescored``: every queued episode scored again at each
            update under the current parameters; ``as_collected``: scored once when collected,
            under the parameters that collected it, and kept with it (the authors' PyBrain
            learners store each step's log-likelihood derivative when the action is taken).

    Examples:
        >>> TrainingSettings(updates=300, episodes_per_update=10, episode_length=15).eval_period
        20
        >>> TrainingSettings(updates=0, episodes_per_update=10, episode_length=15)
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.checks.ArgumentError: updates=0: a positive integer
    """

    updates: int
    episodes_per_update: int
    episode_length: int
    eval_period: int = 20
    eval_episodes: int = 5
    final_episodes: int = 0
    r_lim: float | None = None
    first_run: int = 0
    stop_at_threshold: bool = False
    tensor_rollout: bool = True
    episode_queue: int = 0
    queue_scores: str = "rescored"

    def __post_init__(self) -> None:
        for name in ("updates", "episodes_per_update", "episode_length", "eval_episodes"):
            positive_int(name, getattr(self, name))
        for name in ("eval_period", "episode_queue", "first_run", "final_episodes"):
            non_negative_int(name, getattr(self, name))
        multiple_of("episode_queue", self.episode_queue, "episodes_per_update", self.episodes_per_update)
        one_of("queue_scores", self.queue_scores, QUEUE_SCORES)
        if self.queue_scores == "as_collected" and not self.episode_queue:
            raise ArgumentError("queue_scores", "as_collected", "rescored without an episode queue (episode_queue=0: "
                                "every update's episodes are fresh and scored by the parameters that collected "
                                "them either way), or set episode_queue > 0")
        if self.r_lim is not None and not is_finite_number(self.r_lim):
            raise ArgumentError("r_lim", self.r_lim, "a finite number, or null")
        if self.stop_at_threshold and self.r_lim is None:
            raise ArgumentError("stop_at_threshold", True, "needs a convergence threshold r_lim (not null)")
