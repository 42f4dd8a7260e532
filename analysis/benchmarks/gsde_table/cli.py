"""The table's command line (``python -m analysis.benchmarks.gsde_table run|report``)."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from analysis.benchmarks import gsde_table
from analysis.benchmarks.gsde_table.cells import ALGORITHMS, ALL_ENVS, ENVS, NOISES, RESERVED, cells

#: Where ``run`` writes and ``report`` reads by default.
DEFAULT_OUT = Path("results/gsde_table/runs")
#: Where ``report`` writes the page, its JSON and plots.
DEFAULT_PAGE = Path("docs/gsde_table")

log = logging.getLogger("gsde_table")


def _choices(allowed: tuple[str, ...]):
    def parse(text: str) -> list[str]:
        values = [v.strip() for v in text.split(",") if v.strip()]
        wrong = [v for v in values if v not in allowed]
        if not values or wrong:
            raise argparse.ArgumentTypeError(f"{text!r}: a comma-separated list of {', '.join(allowed)}")
        return values
    return parse


def _seeds(text: str) -> list[int]:
    """``0,1,2`` or ``0-4``."""
    try:
        if "-" in text:
            low, high = (int(v) for v in text.split("-", 1))
            seeds = list(range(low, high + 1))
        else:
            seeds = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        seeds = []
    if not seeds or min(seeds) < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: seeds as 0,1,2 or 0-4 (non-negative)")
    return seeds


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"{text!r}: a fraction of the experiments' budget in (0, 1]")
    return value


def parser() -> argparse.ArgumentParser:
    """The command line's parser."""
    top = argparse.ArgumentParser(prog="python -m analysis.benchmarks.gsde_table",
                                  description=gsde_table.__doc__.split("\n")[0])
    sub = top.add_subparsers(dest="command", required=True)
    run_p = sub.add_parser("run", help="train the cells on both sides (finished runs are skipped)")
    run_p.add_argument("--fraction", type=_fraction, required=True,
                       help="fraction of each experiment's budget (the zoo's: for the PyBullet envs the paper's, "
                            "2M env steps for A2C and PPO, 1M for SAC), both sides")
    run_p.add_argument("--algorithms", type=_choices(ALGORITHMS), default=list(ALGORITHMS),
                       help=f"comma-separated, of {','.join(ALGORITHMS)} (default: all)")
    run_p.add_argument("--envs", type=_choices(ALL_ENVS), default=list(ENVS),
                       help=f"comma-separated, of {','.join(ALL_ENVS)} (default: the paper's, {','.join(ENVS)}; "
                            "mountaincar with sac only)")
    run_p.add_argument("--noises", type=_choices(NOISES), default=list(NOISES),
                       help=f"comma-separated, of {','.join(NOISES)} (default: both)")
    run_p.add_argument("--seeds", type=_seeds, default=[0], help="seeds, as 0,1,2 or 0-4 (default: 0)")
    run_p.add_argument("--workers", type=int, default=2, help="runs at a time (default: 2)")
    run_p.add_argument("--override", action="append", default=[], metavar="KEY=VALUE",
                       help="a train.py override for every cell, both sides (repeatable; e.g. eval_episodes=5, "
                            "algorithm.learning_starts=1000 for SAC at a short budget)")
    run_p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"the folder of runs (default: {DEFAULT_OUT})")
    rep_p = sub.add_parser("report", help="the table, its page, JSON and plots from a folder of runs")
    rep_p.add_argument("folder", type=Path, nargs="?", default=DEFAULT_OUT)
    rep_p.add_argument("--out", type=Path, default=DEFAULT_PAGE, help=f"where the page goes (default: {DEFAULT_PAGE})")
    return top


def main(argv: list[str] | None = None) -> int:
    """Command line: ``run`` the cells, ``report`` a folder of runs."""
    top = parser()
    args = top.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    if args.command == "report":
        from analysis.benchmarks.gsde_table.report import report

        report(args.folder, args.out)
        log.info("wrote %s (gsde_table.md, gsde_table.json, gsde_table_<env>.png)", args.out)
        return 0
    if args.workers < 1:
        top.error(f"--workers must be at least 1, got {args.workers}")
    for override in args.override:
        if "=" not in override or override.split("=", 1)[0].lstrip("+~") in RESERVED:
            top.error(f"--override {override!r}: KEY=VALUE, not {' or '.join(RESERVED)} "
                      "(the cells and --fraction set them)")
    try:
        table = cells(args.algorithms, args.envs, args.noises, args.seeds)
    except ValueError as error:
        top.error(str(error))
    from analysis.benchmarks.gsde_table.run import FolderMismatch, run_table
    from analysis.benchmarks.gsde_table.sb3 import UnmappableSetting

    try:
        done, total, failures = run_table(table, args.fraction, args.override, args.out, args.workers)
    except (FolderMismatch, UnmappableSetting) as error:
        sys.stderr.write(f"error: {error}\n")
        return 2
    report_command = "python -m analysis.benchmarks.gsde_table report" + \
        ("" if args.out == DEFAULT_OUT else f" {args.out}")
    log.info("%d of %d runs done%s; report: %s", done, total,
             f" ({len(failures)} failed: see above)" if failures else "", report_command)
    return 1 if failures else 0
