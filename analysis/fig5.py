"""Ball catching, paper Fig. 5 (REINFORCE) and Fig. 6 (ENAC): learning curves and catch counts.

Reads one or more sweep directories (shards of the same sweep may be split over processes or
machines: runs are merged by their global index, a run found twice must agree), keeps the runs
of one estimator, and writes into ``--out DIR``:

- ``fig5.png`` (``fig6.png`` for ENAC): left, the deterministic evaluation returns over the
  updates, mean ± std over runs, SDE and REX; right, the cumulative number of runs whose best
  evaluated policy reached R ≥ -2.0, -1.5, -1.1, -1.0;
- ``fig5.json`` / ``fig5.md``: those counts per explorer, best and final, beside the paper's.

Usage:
    python analysis/fig5.py --out results/fig5 multirun/2026-11-22/10-00-00 [more shards...]
    python analysis/fig5.py --estimator enac --out results/fig6 SWEEP_DIR
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
from pathlib import Path

#: Levels of the paper's right-hand plots: "slowed down", "kept on the fingers", "catch",
#: "good catch".
LEVELS = (-2.0, -1.5, -1.1, -1.0)
#: The paper's counts out of 100 runs where it states them (section 4.2).
PAPER = {
    "reinforce": {"sde": {-1.0: 68, -1.1: 98}, "rex": {-1.0: 7}},
    "enac": {"sde": {-1.1: 93}, "rex": {-1.1: 67}},  # "SDE outperformed REX by over 38%"
}
FIGURE = {"reinforce": "fig5", "enac": "fig6"}


def load_runs(directories: list[Path], estimator: str) -> dict[str, dict[int, dict]]:
    """``explorer → global run index → {"evals": [(update, return)], "final": R}``, returns as
    mean rewards per step (the paper's levels) whatever the job's ``episode_return``."""
    from sde_torchrl.run_dir import read_summary  # names a damaged summary.json and the remedy
    from sde_torchrl.summary import mean_reward_factor

    runs: dict[str, dict[int, dict]] = {}
    for directory in directories:
        for summary_path in sorted(directory.rglob("summary.json")):
            summary = read_summary(summary_path)
            if summary.get("estimator") != estimator:
                continue
            explorer, scale = summary["explorer"], mean_reward_factor(summary)
            evals: dict[int, list[tuple[int, float]]] = {}
            with open(summary_path.parent / "metrics.csv") as f:
                for row in csv.DictReader(f):
                    if row["eval_return"]:
                        evals.setdefault(int(row["run"]), []).append(
                            (int(row["update"]), scale * float(row["eval_return"])))
            for offset, final in enumerate(summary["final_eval_return"]):
                index = summary["first_run"] + offset
                run = {"evals": evals[index], "final": scale * final}
                previous = runs.setdefault(explorer, {}).setdefault(index, run)
                if previous != run:
                    raise ValueError(f"run {index} of {explorer} appears twice with different results "
                                     f"(second copy in {summary_path.parent})")
    return runs


def counts(runs: dict[int, dict]) -> dict[str, dict[str, int]]:
    """Runs whose best (and whose final) evaluated policy reached each level."""
    best = [max(r for _, r in run["evals"]) for run in runs.values()]
    final = [run["final"] for run in runs.values()]
    return {
        "best": {f"{level}": sum(b >= level for b in best) for level in LEVELS},
        "final": {f"{level}": sum(f >= level for f in final) for level in LEVELS},
    }


def report(runs: dict[str, dict[int, dict]], estimator: str) -> dict:
    """The figure's numbers: per explorer, run count, catch counts and the paper's."""
    return {
        "estimator": estimator,
        "explorers": {
            explorer: {"runs": len(by_run), **counts(by_run),
                       "paper": {f"{k}": v for k, v in PAPER[estimator].get(explorer, {}).items()}}
            for explorer, by_run in sorted(runs.items())
        },
    }


def write_markdown(result: dict, path: Path) -> None:
    """Counts per level, ours (best / final evaluated policy) beside the paper's."""
    lines = ["| explorer | runs | " + " | ".join(f"R ≥ {level}" for level in LEVELS) + " |",
             "| --- | --- | " + " | ".join("---" for _ in LEVELS) + " |"]
    for explorer, stats in result["explorers"].items():
        cells = []
        for level in LEVELS:
            paper = stats["paper"].get(f"{level}")
            cells.append(f"{stats['best'][f'{level}']} / {stats['final'][f'{level}']}"
                         + (f" (paper {paper})" if paper is not None else ""))
        lines.append(f"| {explorer.upper()} | {stats['runs']} | " + " | ".join(cells) + " |")
    lines += ["", "Cells: runs whose best / final deterministic evaluation reached the level; "
              "the paper's count (out of 100) where it states one."]
    path.write_text("\n".join(lines) + "\n")


def plot(runs: dict[str, dict[int, dict]], result: dict, path: Path, title: str) -> None:
    """Left: evaluation curves (mean ± std); right: cumulative catch counts."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(9, 3.4))
    styles = {"sde": {"color": "tab:blue", "ls": "-"}, "rex": {"color": "tab:red", "ls": "--"}}
    for explorer, by_run in sorted(runs.items()):
        updates = sorted({u for run in by_run.values() for u, _ in run["evals"]})
        table = [[dict(run["evals"]).get(u) for run in by_run.values()] for u in updates]
        mean = [statistics.mean(v for v in row if v is not None) for row in table]
        std = [statistics.pstdev([v for v in row if v is not None]) for row in table]
        x = [u + 1 for u in updates]
        left.plot(x, mean, label=explorer.upper(), **styles.get(explorer, {}))
        left.fill_between(x, [m - s for m, s in zip(mean, std, strict=True)],
                          [m + s for m, s in zip(mean, std, strict=True)],
                          color=styles.get(explorer, {}).get("color"), alpha=0.2)
        best = result["explorers"][explorer]["best"]
        right.plot([str(level) for level in LEVELS], [best[f"{level}"] for level in LEVELS], marker="o",
                   label=explorer.upper(), **styles.get(explorer, {}))
    left.set(xlabel="policy updates", ylabel="deterministic return R", title=title)
    right.set(xlabel="level: runs with R ≥ level", ylabel="number of runs", title="runs reaching a level")
    left.legend(loc="lower right")
    right.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None, estimator: str = "reinforce") -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sweeps", nargs="+", type=Path, help="sweep or run directories (shards)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--estimator", choices=sorted(FIGURE), default=estimator)
    args = parser.parse_args(argv)
    runs = load_runs(args.sweeps, args.estimator)
    if not runs:
        print(f"error: no {args.estimator} runs under {[str(s) for s in args.sweeps]}", file=sys.stderr)
        return 1
    args.out.mkdir(parents=True, exist_ok=True)
    name = FIGURE[args.estimator]
    result = report(runs, args.estimator)
    (args.out / f"{name}.json").write_text(json.dumps(result, indent=2))
    write_markdown(result, args.out / f"{name}.md")
    plot(runs, result, args.out / f"{name}.png", f"ball catching, {args.estimator.upper()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
