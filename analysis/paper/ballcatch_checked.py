"""Ball catching with the headline learner: SDE against REX, each run's best policy kept and
checked, with its final one, on fresh balls.

Reads the jobs of ``+experiment=ballcatch_checked_sweep`` (one sweep directory per explorer; each
job's ``summary.json`` holds its final check) and writes ``checked.json`` and ``checked.md`` into
``--out``: per explorer, how many runs' best policies catch on the fresh balls (a mean reward per
step of at least -1.1 over them, the paper's catch), how many reached a catch at a periodic
evaluation in training, how many ended with one (their last evaluation) and how many final
policies catch on the fresh balls; the same for good catches (-1.0); 95 % Wilson intervals, and
SDE − REX with its bootstrap interval over runs; and what the best policies did with the fresh
balls (held, kept on the hand, dropped).

Usage:
    python -m analysis.paper.ballcatch_checked --out docs/study/ballcatch/checked \
        results/ballcatch/runs/checked/sde results/ballcatch/runs/checked/rex
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from analysis.figures import bounds, difference_of_means, write_page_json
from analysis.sweeps import EXIT_REFUSED, finished_jobs

#: The measures, in the page's order: (key, what the page calls it).
MEASURES = (
    ("best_checked", "best policy: {level} on the fresh balls"),
    ("reached", "{level} reached in training"),
    ("final", "last evaluation: {level}"),
    ("final_checked", "final policy: {level} on the fresh balls"),
)
#: The levels counted, by name: a catch includes a good catch.
LEVELS = {"catch": ("good catch", "catch"), "good catch": ("good catch",)}
#: The explorers compared, in the page's order.
EXPLORERS = ("sde", "rex")


def run_flags(summary: dict, levels: tuple[str, ...]) -> dict[str, list[bool]]:
    """Per run of one job, whether each :data:`MEASURES` holds at ``levels``.

    Examples:
        >>> summary = {"best_check_level": ["catch", "slowed"], "final_check_level": ["dropped", "slowed"],
        ...            "final_eval_level": ["good catch", "dropped"],
        ...            "level_first_update": [{"good catch": 99, "catch": 59}, {"good catch": None, "catch": None}]}
        >>> run_flags(summary, ("good catch", "catch"))  # doctest: +NORMALIZE_WHITESPACE
        {'best_checked': [True, False], 'reached': [True, False], 'final': [True, False],
         'final_checked': [False, False]}
    """
    return {
        "best_checked": [level in levels for level in summary["best_check_level"]],
        "reached": [any(first.get(level) is not None for level in levels) for first in summary["level_first_update"]],
        "final": [level in levels for level in summary["final_eval_level"]],
        "final_checked": [level in levels for level in summary["final_check_level"]],
    }


def load(sweeps: list[Path]) -> dict[str, dict]:
    """Per explorer, its jobs' summaries in run order; a job without a final check is refused."""
    found: dict[str, dict[int, dict]] = {}
    for job in finished_jobs(*sweeps):
        summary = job.summary
        if "best_check_level" not in summary:
            print(f"error: {job.path} has no final check (summary.json without best_check_level): run it with "
                  "final_episodes > 0, as +experiment=ballcatch_checked_sweep does", file=sys.stderr)
            raise SystemExit(EXIT_REFUSED)
        found.setdefault(summary["explorer"], {})[summary["first_run"]] = summary
    missing = [explorer for explorer in EXPLORERS if explorer not in found]
    if missing:
        print(f"error: no {' or '.join(missing)} jobs under {[str(s) for s in sweeps]}", file=sys.stderr)
        raise SystemExit(EXIT_REFUSED)
    return {explorer: [found[explorer][first] for first in sorted(found[explorer])] for explorer in EXPLORERS}


def numbers(jobs: dict[str, list[dict]]) -> dict:
    """The page's numbers from each explorer's summaries."""
    from sde_torchrl.envs.ballcatch.outcomes import BEHAVIOURS
    from sde_torchrl.utils.intervals import binomial_interval, bootstrap_interval

    flags: dict[str, dict[str, dict[str, list[bool]]]] = {}
    result: dict = {"explorers": {}, "sde_minus_rex": {}}
    for explorer, summaries in jobs.items():
        flags[explorer] = {}
        for name, levels in LEVELS.items():
            per_job = [run_flags(summary, levels) for summary in summaries]
            flags[explorer][name] = {key: [flag for job in per_job for flag in job[key]] for key, _ in MEASURES}
        runs = len(flags[explorer]["catch"]["reached"])
        behaviours = {label: sum(counts[label] for summary in summaries for counts in summary["best_check_behaviours"])
                      for label in BEHAVIOURS}
        first = summaries[0]
        result["explorers"][explorer] = {
            "runs": runs, "seed": first["seed"], "episodes": first["check_episodes"],
            "counts": {name: {key: sum(values) for key, values in by_key.items()}
                       for name, by_key in flags[explorer].items()},
            "intervals": {name: {key: bounds(binomial_interval(sum(values), runs)) for key, values in by_key.items()}
                          for name, by_key in flags[explorer].items()},
            "best_policy_episodes": behaviours,
        }
    for name in LEVELS:
        result["sde_minus_rex"][name] = {}
        for key, _ in MEASURES:
            sde = [float(flag) for flag in flags["sde"][name][key]]
            rex = [float(flag) for flag in flags["rex"][name][key]]
            estimate, low, high = bootstrap_interval((sde, rex), difference_of_means)
            result["sde_minus_rex"][name][key] = {"estimate": estimate, "interval": [low, high],
                                                  "significant": not low <= 0.0 <= high}
    return result


def _share(count: int, runs: int, interval: list[float]) -> str:
    return f"{count} ({round(100 * count / runs)} % [{round(100 * interval[0])}, {round(100 * interval[1])}])"


def markdown(result: dict, sweeps: list[str]) -> str:
    """The page: one table per level, the runs of each explorer, SDE − REX."""
    sde, rex = result["explorers"]["sde"], result["explorers"]["rex"]
    lines = [
        f"Runs of the headline learner (`+experiment=ballcatch`: ENAC + SDE at the paper's Fig. 6 setting, REX the "
        f"same learner with `explorer=rex`), {sde['runs']} per explorer on seed {sde['seed']}. Each run's best "
        f"policy (by its periodic evaluations) and its final policy were both run on the same {sde['episodes']} "
        "fresh balls at the end; a policy catches when its mean reward per step over them is at least −1.1 "
        "(a good catch: −1.0). Each cell: runs, their percent and its 95 % Wilson interval; SDE − REX in "
        "percentage points with its bootstrap interval (significant where it excludes 0).",
        "",
    ]
    for name in LEVELS:
        lines += [f"| {name} | SDE | REX | SDE − REX |", "| --- | --- | --- | --- |"]
        for key, label in MEASURES:
            difference = result["sde_minus_rex"][name][key]
            low, high = difference["interval"]
            mark = " (significant)" if difference["significant"] else ""
            shares = [_share(side["counts"][name][key], side["runs"], side["intervals"][name][key])
                      for side in (sde, rex)]
            lines.append(f"| {label.format(level=f'a {name}')} | {shares[0]} | {shares[1]} | "
                         f"{100 * difference['estimate']:+.0f} [{100 * low:+.0f}, {100 * high:+.0f}]{mark} |")
        lines.append("")
    for explorer, stats in (("SDE", sde), ("REX", rex)):
        episodes = stats["best_policy_episodes"]
        total = sum(episodes.values())
        lines.append(f"- {explorer}'s best policies, over their {total} fresh balls: "
                     + ", ".join(f"{episodes[label]} {label}" for label in ("held", "kept on the hand", "dropped"))
                     + ".")
    lines += ["", "Sweeps: " + ", ".join(f"`{path}`" for path in sweeps) + ".", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__.splitlines()[0])
    parser.add_argument("sweeps", nargs="+", type=Path, help="the sweep directories of both explorers")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    result = numbers(load(args.sweeps))
    repo = Path(__file__).resolve().parents[2]
    shown = [str(p.resolve().relative_to(repo)) if p.resolve().is_relative_to(repo) else str(p) for p in args.sweeps]
    args.out.mkdir(parents=True, exist_ok=True)
    write_page_json(args.out / "checked.json", {**result, "sweeps": shown})
    (args.out / "checked.md").write_text(markdown(result, shown))
    sde, rex = result["explorers"]["sde"], result["explorers"]["rex"]
    print(f"wrote {args.out / 'checked.md'}: best policies catching on fresh balls, SDE "
          f"{sde['counts']['catch']['best_checked']} of {sde['runs']}, REX {rex['counts']['catch']['best_checked']} "
          f"of {rex['runs']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
