"""What an env says of a finished job beyond its returns: the levels its runs reached, the lines
that close the job's log and what a multirun's comparison counts.

An env's schema declares its report (``outcomes`` of
:class:`~sde_torchrl.config.schemas.envs.EnvConf`), which registers it here under the env's
option; the summary (:mod:`sde_torchrl.trainers.summary`) and the comparison
(:mod:`sde_torchrl.trainers.comparison`) find it by the ``env`` a summary records. An env without
a report is summarised by its returns alone. The report works on plain data: the summary, the
periodic evaluations and the final check's outcomes, with ``scale``, what turns the summary's
returns into the paper's mean reward per step.

Examples:
    >>> report_for("no such env") is None
    True
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

#: env option → what makes its report (imported on first use: a report may need torch).
_REPORTS: dict[str, Callable[[], OutcomeReport]] = {}


class OutcomeReport:
    """An env's report on a finished job; this base reports nothing beyond the returns."""

    def entries(self, summary: dict[str, Any], scale: float, evaluations: dict[int, list[float]] | None,
                outcomes: dict[str, Any] | None) -> dict[str, Any]:
        """What ``summary.json`` records beyond the returns.

        Args:
            summary: the job's summary so far.
            scale: the factor onto the paper's mean reward per step.
            evaluations: update → each run's periodic deterministic return; ``None``: not known.
            outcomes: per policy checked (``final``, ``best``), what the env reported of the final
                check's episodes; ``None``: nothing.
        """
        return {}

    def lines(self, summary: dict[str, Any], scale: float) -> list[str] | None:
        """The lines that end the job's log after the last training return; ``None``: the
        returns' lines."""
        return None

    def shares(self, summary: dict[str, Any]) -> dict[str, list[bool]]:
        """What a multirun's comparison counts over runs: a phrase ("last evaluation a catch") →
        whether each run achieved it."""
        return {}


def declare_report(env: str, report: Callable[[], OutcomeReport]) -> None:
    """Registers what makes the report of the env option ``env``."""
    _REPORTS[env] = report


def report_for(env: str | None) -> OutcomeReport | None:
    """The report of the env option ``env`` (a summary's ``env``), ``None`` for an env without one."""
    make = _REPORTS.get(env) if env is not None else None
    return make() if make is not None else None
