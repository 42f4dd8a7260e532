"""What a job records while it trains, and the summary computed from it (``summary.json``)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import torch
from torch import nn

from sde_torchrl.envs.outcomes import report_for
from sde_torchrl.jobs.metrics import RECORDS


@dataclass
class LoopState:
    """What the summary is computed from, and where the loop stands (checkpointed).

    Attributes:
        update: updates done.
        reached: per run, whether an update's mean return exceeded ``r_lim``.
        records: per update, the statistics :data:`~sde_torchrl.jobs.metrics.RECORDS` declares,
            under their checkpoint keys: ``returns``, the mean exploratory return of each run
            ``[runs]`` (also :attr:`returns`); ``grad_norms``, each run's gradient norm ``[runs]``;
            ``explorations``, each run's :func:`exploration_state` after it, ``[3, runs]``. With
            ``evals``, what ``metrics.csv`` is verified against, and rebuilt from
            (:meth:`record`, :func:`~sde_torchrl.jobs.metrics.recorded_rows`).
        evals: update index → mean deterministic return of each run ``[runs]``.
        wall_s: training time of earlier sessions of this job (resumed jobs).
        finished: the job ran to its end.
        queue: with an episode queue, its episodes ``[runs, Q, T]`` as a nested dict of tensors.
        best: each run's best policy so far (:meth:`~sde_torchrl.trainers.best.BestPolicy.state_dict`).
        final_check: the final and the best policies' returns on the job's fresh episodes
            (``final_episodes``), once the job has ended: ``{"final": [runs, E], "best": [runs, E]}``
            and, where the env reports them, the episodes' outcomes under ``"outcomes"``.

    Examples:
        >>> state = LoopState(update=0, reached=torch.zeros(2, dtype=torch.bool))
        >>> state.add({"return_mean": torch.tensor([-1.0, -2.0]), "grad_norm": torch.ones(2),
        ...            "exploration": torch.ones(3, 2)})
        >>> state.update = 1
        >>> restored = LoopState.from_state_dict(state.state_dict())
        >>> restored.update, restored.returns
        (1, [tensor([-1., -2.])])
    """

    update: int
    reached: torch.Tensor
    records: dict[str, list[torch.Tensor]] = field(default_factory=lambda: {r.key: [] for r in RECORDS})
    evals: dict[int, torch.Tensor] = field(default_factory=dict)
    wall_s: float = 0.0
    finished: bool = False
    queue: dict[str, Any] | None = None
    best: dict[str, Any] | None = None
    final_check: dict[str, Any] | None = None

    @property
    def returns(self) -> list[torch.Tensor]:
        """Per update, the mean exploratory return of each run ``[runs]``."""
        return self.records["returns"]

    def add(self, statistics: dict[str, torch.Tensor]) -> None:
        """Keeps an update's :data:`~sde_torchrl.jobs.metrics.RECORDS` statistics (what the
        trainer's update returned)."""
        for record in RECORDS:
            self.records[record.key].append(statistics[record.statistic])

    def record(self) -> dict[str, Any]:
        """What :func:`~sde_torchrl.jobs.metrics.recorded_rows` reads: ``update``, ``evals`` and
        the per-update records (as a checkpoint's ``loop`` holds them, unstacked)."""
        return {"update": self.update, "evals": self.evals, **self.records}

    def state_dict(self) -> dict[str, Any]:
        """The state as tensors and plain data; the per-update records stacked, ``[updates, runs]``
        (one tensor each: a checkpoint stays small and quick to write after thousands of updates)."""
        runs = len(self.reached)
        records = {r.key: (torch.stack(self.records[r.key]) if self.records[r.key]
                           else self.reached.new_zeros((0, *r.shape, runs), dtype=torch.float32)) for r in RECORDS}
        return {"update": self.update, "reached": self.reached.clone(), **records,
                "evals": {k: v.clone() for k, v in self.evals.items()},
                "wall_s": self.wall_s, "finished": self.finished, "queue": self.queue, "best": self.best,
                "final_check": self.final_check}

    @classmethod
    def from_state_dict(cls, state: dict[str, Any]) -> LoopState:
        records = {r.key: list(state[r.key].unbind(0)) for r in RECORDS}
        return cls(**{key: value for key, value in state.items() if key not in records}, records=records)


def exploration_state(policy: nn.Module, runs: int) -> torch.Tensor:
    """Per run: the smallest and the largest exploration scale and the largest controller
    parameter in magnitude, ``[3, runs]`` (``metrics.csv``'s ``sigma_min``, ``sigma_max``,
    ``weight_max``).

    The scales are the explorer's ``exploration_scale()``: SDE's ``σ̂`` (eq. 23) element by
    element, PGPE's ``|σ|``. A run whose ``sigma_max`` has fallen to about 0 no longer explores
    (its gradient is then noise-free and tiny, or, with the authors' rescale, arbitrary); a
    growing ``weight_max`` shows a controller pushed into the tanh's flat ends.

    Args:
        policy: the policy; parameters of its exploring module (the one with
            ``exploration_scale``) are not counted as controller parameters.
        runs: the job's runs (the leading dimension of stacked parameters).

    Examples:
        >>> from sde_torchrl import LinearActor, SDEParams, make_sde_actor
        >>> policy = make_sde_actor(LinearActor(3, 2, init=-0.5, runs=2), SDEParams(2, 3, init_param=-2.0, runs=2))
        >>> exploration_state(policy, 2)
        tensor([[0.1353, 0.1353],
                [0.1353, 0.1353],
                [0.5000, 0.5000]])
    """
    explorer = next((m for m in policy.modules() if hasattr(type(m), "exploration_scale")), None)
    own = {id(p) for p in explorer.parameters()} if explorer is not None else set()
    weights = [p.detach().reshape(runs, -1) for p in policy.parameters() if id(p) not in own]
    device = next(policy.parameters()).device
    nan = torch.full((runs,), float("nan"), device=device)
    scale = explorer.exploration_scale().reshape(runs, -1) if explorer is not None else None
    return torch.stack([
        scale.min(-1).values if scale is not None else nan,
        scale.max(-1).values if scale is not None else nan,
        torch.cat(weights, -1).abs().max(-1).values if weights else nan,
    ]).float()


def summarize(
    state: LoopState, settings: Any, policy: nn.Module, episodes_after: Callable[[int], int],
) -> dict[str, Any]:
    """The job's summary: per-run initial and final returns, the final deterministic
    evaluation, episodes to the threshold, final parameters, env steps, wall time.

    Args:
        state: the finished loop's record.
        settings: the job's :class:`~sde_torchrl.trainers.trainer.TrainingSettings` (a dataclass).
        policy: the trained policy (its parameters carry a leading ``[runs]`` dimension).
        episodes_after: episodes each run has collected by the end of a (0-based) update.
    """
    returns = torch.stack(state.returns).cpu()  # [updates, runs]
    runs = returns.shape[1]
    above = returns > settings.r_lim if settings.r_lim is not None else torch.zeros_like(returns, dtype=torch.bool)
    first = [int(above[:, r].nonzero()[0]) if bool(above[:, r].any()) else None for r in range(runs)]
    updates_done = len(state.returns)
    return {
        "runs": runs,
        "first_run": settings.first_run,
        "settings": asdict(settings),
        "updates_done": updates_done,
        "initial_return": returns[0].tolist(),
        "final_return": returns[-1].tolist(),
        "final_eval_return": state.evals[updates_done - 1].cpu().tolist(),
        "episodes_to_threshold": [None if i is None else episodes_after(i) for i in first],
        "final_parameters": {  # named as in checkpoint.pt's policy state dict
            name: p.detach().reshape(runs, -1).cpu().tolist() for name, p in policy.named_parameters()
        },
        "env_steps": episodes_after(updates_done - 1) * settings.episode_length * runs,
        "wall_s": state.wall_s,
    }


def best_and_checked(state: LoopState) -> dict[str, Any]:
    """What ``summary.json`` records of the runs' best policies and the final check: per run,
    the update of the best policy (0-based, as ``metrics.csv`` counts) and the evaluation that
    chose it; with a final check, the mean return of the final and the best policies over the
    fresh episodes (``final_check_return``, ``best_check_return``) and those episodes' count.

    Examples:
        >>> state = LoopState(update=2, reached=torch.zeros(1, dtype=torch.bool))
        >>> state.best = {"update": torch.tensor([1]), "score": torch.tensor([-1.5], dtype=torch.float64)}
        >>> state.final_check = {"episodes": 2, "final": [[-2.0, -1.0]], "best": [[-1.0, -1.0]]}
        >>> best_and_checked(state)  # doctest: +NORMALIZE_WHITESPACE
        {'best_update': [1], 'best_eval_return': [-1.5], 'check_episodes': 2, 'final_check_return': [-1.5],
         'best_check_return': [-1.0]}
    """
    out: dict[str, Any] = {}
    if state.best is not None:
        out.update(best_update=state.best["update"].tolist(), best_eval_return=state.best["score"].tolist())
    if state.final_check is not None:
        out["check_episodes"] = state.final_check["episodes"]
        for name in ("final", "best"):
            out[f"{name}_check_return"] = [sum(run) / len(run) for run in state.final_check[name]]
    return out


def per_step_factor(episode_return: str, episode_length: int) -> float:
    """What turns a return in the ``episode_return`` definition into the paper's mean reward per
    step: ``1 / episode_length`` for summed rewards (the authors' learner), else 1.

    Examples:
        >>> per_step_factor("sum", 500), per_step_factor("mean", 500)
        (0.002, 1.0)
    """
    return 1.0 / episode_length if episode_return == "sum" else 1.0


def mean_reward_factor(summary: dict[str, Any]) -> float:
    """What turns the returns that ``summary.json`` and ``metrics.csv`` report into the paper's
    mean reward per step: ``1 / episode_length`` for a job that regressed on summed rewards
    (``estimator.episode_return=sum``, the authors' learner), else 1.

    The paper's thresholds and curves (section 4.2: ``R ≥ -1.1``, ``-1.0``) are mean rewards,
    whatever the learner regresses on.

    Examples:
        >>> mean_reward_factor({"episode_return": "sum", "settings": {"episode_length": 500}})
        0.002
        >>> mean_reward_factor({"episode_return": "mean", "settings": {"episode_length": 500}})
        1.0
    """
    if summary.get("episode_return") != "sum":
        return 1.0  # a mean-return job need not record its episode length
    return per_step_factor("sum", summary["settings"]["episode_length"])


def final_levels(summary: dict[str, Any], state: LoopState | None = None) -> dict[str, Any]:
    """What the env's report (:func:`~sde_torchrl.envs.outcomes.report_for`, by the summary's
    ``env``) adds to ``summary.json``, such as the levels its runs reached; nothing for an env
    without a report. With the loop's ``state``, the report also sees the periodic evaluations
    and what the env reported of the final check's episodes.

    Examples:
        >>> final_levels({"env": "minimize", "final_eval_return": [-1.0]})
        {}
    """
    report = report_for(summary.get("env"))
    if report is None:
        return {}
    evaluations = {k: v.cpu().double().tolist() for k, v in state.evals.items()} if state is not None else None
    outcomes = ((state.final_check or {}).get("outcomes") or {}) if state is not None else None
    return report.entries(summary, mean_reward_factor(summary), evaluations, outcomes)


def final_lines(summary: dict[str, Any]) -> list[str]:
    """The lines that end a job's log: the last training return (exploratory episodes, which a
    learner that explores widely keeps below its evaluation), then each run's final deterministic
    evaluation, the result, last; both in the estimator's return definition. An env with a report
    says what follows the training return its own way.

    Examples:
        >>> final_lines({"env": "minimize", "final_eval_return": [-1.23456], "final_return": [-2.0]})
        ['last training return per run: [-2.0]', 'final evaluation per run (no exploration): [-1.235]']
    """
    training = f"last training return per run: {[round(value, 3) for value in summary['final_return']]}"
    reported = _reported_lines(summary)
    if reported is not None:
        return [training, *reported]
    evals = [round(value, 3) for value in summary["final_eval_return"]]
    lines = [training, f"final evaluation per run (no exploration): {evals}"]
    if "best_check_return" in summary:
        lines.extend(checked_lines(summary))
    return lines


def checked_lines(summary: dict[str, Any]) -> list[str]:
    """What the final check found: the env's report's lines, else the mean returns of the best and
    the final policies on the fresh episodes.

    Examples:
        >>> checked_lines({"env": "minimize", "check_episodes": 5, "best_update": [7], "best_check_return": [-1.0],
        ...                "final_check_return": [-1.25]})
        ['on 5 fresh episodes per run: best policy (update [7]) [-1.0], final policy [-1.25]']
    """
    reported = _reported_lines(summary)
    if reported is not None:
        return reported
    best = [round(value, 3) for value in summary["best_check_return"]]
    final = [round(value, 3) for value in summary["final_check_return"]]
    return [f"on {summary['check_episodes']} fresh episodes per run: best policy (update "
            f"{summary['best_update']}) {best}, final policy {final}"]


def _reported_lines(summary: dict[str, Any]) -> list[str] | None:
    report = report_for(summary.get("env"))
    return report.lines(summary, mean_reward_factor(summary)) if report is not None else None
