"""The SAC benchmark's command line (``python -m analysis.benchmarks.bench_sac``)."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from pathlib import Path

from analysis.benchmarks import bench_sac
from analysis.benchmarks.bench_sac.speed import SPEED_VARIANTS, WARM_UP, speed
from analysis.benchmarks.bench_sac.update_speed import EXPERIMENTS, VARIANTS, update_speed


def _write(out: Path | None, argv: list[str] | None, text: str) -> None:
    """Writes ``text`` to ``out`` under a line with the command and the date."""
    if out is None:
        return
    command = " ".join(["python -m analysis.benchmarks.bench_sac", *(argv if argv is not None else sys.argv[1:])])
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(f"Written by `{command}` on {time.strftime('%Y-%m-%d')} ({os.cpu_count()} cores).\n\n" + text)


def main(argv: list[str] | None = None) -> int:
    """Command line: ``speed`` of whole rounds, ``update-speed`` of single gradient steps."""
    parser = argparse.ArgumentParser(prog="python -m analysis.benchmarks.bench_sac",
                                     description=bench_sac.__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    round_p = sub.add_parser("speed", help="env steps per second of train.py's SAC job and SB3's, fresh processes")
    round_p.add_argument("variants", nargs="+", choices=SPEED_VARIANTS)
    round_p.add_argument("--rounds", type=int, default=30, help=f"rounds per process (the first {WARM_UP} not timed)")
    round_p.add_argument("--repeats", type=int, default=1, help="times the whole list of variants runs")
    round_p.add_argument("--out", type=Path, default=None, help="also write the table to this markdown file")
    step_p = sub.add_parser("update-speed", help="ms per gradient step of each variant, interleaved in one process")
    step_p.add_argument("variants", nargs="+", choices=tuple(VARIANTS))
    step_p.add_argument("--env", choices=tuple(EXPERIMENTS), default="mountaincar")
    step_p.add_argument("--updates", type=int, default=100, help="gradient steps per timing")
    step_p.add_argument("--rounds", type=int, default=3, help="timed rounds (after one warm-up round)")
    step_p.add_argument("--profile", action="store_true", help="split the job's eager step by function")
    step_p.add_argument("--out", type=Path, default=None, help="also write the tables to this markdown file")
    args = parser.parse_args(argv)
    import torchrl  # noqa: F401  (sets its logger up; then quieten it: its INFO lines go to stdout)

    logging.getLogger("torchrl").setLevel(logging.WARNING)
    if args.command == "speed":
        if args.rounds < WARM_UP + 2 or args.repeats < 1:
            parser.error(f"--rounds must be at least {WARM_UP + 2} and --repeats at least 1, "
                         f"got {args.rounds} and {args.repeats}")
        text = speed(args.variants, args.rounds, args.repeats)
    else:
        if args.updates <= 0 or args.rounds <= 0:
            parser.error(f"--updates and --rounds must be positive, got {args.updates} and {args.rounds}")
        text = update_speed(args.env, args.updates, args.rounds, args.variants, args.profile)
    _write(args.out, argv, text)
    sys.stdout.write(text)
    return 0
