"""The lines that end a multirun: one per method (the jobs' overrides that differ, seeds and
shards aside), comparing what its runs reached, with 95 % intervals."""

from __future__ import annotations

from typing import Any

from sde_torchrl.envs.outcomes import report_for

#: Overrides that split one method's runs over jobs rather than tell methods apart.
SHARDING = ("seed", "first_run")


def job_result(overrides: list[str], summary: dict[str, Any]) -> dict[str, Any]:
    """What a finished job of a multirun reports for the comparison: its overrides, each run's
    final evaluation (in the paper's mean reward per step where the summary has it) and, where
    the env has a report (:func:`~sde_torchrl.envs.outcomes.report_for`), what it counts per run
    (``shares``: a phrase → whether each run achieved it)."""
    report = report_for(summary.get("env"))
    return {"overrides": [o for o in overrides if not o.startswith("hydra.")],
            "final_eval": summary.get("final_eval_mean_reward", summary["final_eval_return"]),
            "shares": report.shares(summary) if report is not None else {}}


def method_label(overrides: list[str], shared: set[str]) -> str:
    """A job's method: its overrides but the shared ones and those of :data:`SHARDING`.

    Examples:
        >>> method_label(["explorer=rex", "seed=3", "+experiment=minimize"], {"+experiment=minimize"})
        'explorer=rex'
    """
    kept = [o for o in overrides if o not in shared and o.split("=", 1)[0].lstrip("+~") not in SHARDING]
    return " ".join(kept) or "all jobs"


def comparison_lines(results: list[dict[str, Any]]) -> list[str]:
    """One line per method of a multirun's finished jobs: its runs, the mean final evaluation
    with its bootstrap interval over runs and, for what the env's report counts (its ``shares``,
    such as the runs whose last evaluation is a catch), how many runs achieved it (Wilson intervals).

    Examples:
        >>> jobs = [{"overrides": ["explorer=sde", "seed=0"], "final_eval": [-1.0, -2.0]},
        ...         {"overrides": ["explorer=rex", "seed=0"], "final_eval": [-3.0]}]
        >>> comparison_lines(jobs)[1]
        'explorer=rex: 1 run in 1 job; final evaluation mean -3.000 [-3.000, -3.000]'
    """
    from sde_torchrl.utils.intervals import binomial_interval, bootstrap_interval  # scipy: only to compare

    if not results:
        return []
    shared = set.intersection(*(set(result["overrides"]) for result in results))
    methods: dict[str, list[dict[str, Any]]] = {}
    for result in results:
        methods.setdefault(method_label(result["overrides"], shared), []).append(result)
    lines = []
    for label, jobs in methods.items():
        values = [value for job in jobs for value in job["final_eval"]]
        interval = bootstrap_interval(values)
        runs = len(values)
        line = (f"{label}: {runs} run{'s' if runs > 1 else ''} in {len(jobs)} job{'s' if len(jobs) > 1 else ''}; "
                f"final evaluation mean {interval.estimate:.3f} [{interval.low:.3f}, {interval.high:.3f}]")
        for what in jobs[0].get("shares", {}):
            if all(what in job.get("shares", {}) for job in jobs):
                count = sum(job["shares"][what].count(True) for job in jobs)
                share = binomial_interval(count, runs)
                line += (f"; {what} in {count} ({round(100 * share.estimate)} % "
                         f"[{round(100 * share.low)}, {round(100 * share.high)}])")
        lines.append(line)
    return lines


__all__ = ["comparison_lines", "job_result", "method_label"]
