"""The PPO benchmark's command line (``python -m analysis.benchmarks.bench_ppo``)."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from analysis.benchmarks import bench_ppo
from analysis.benchmarks.bench_ppo.speed import SPEED_VARIANTS, phases, speed


def main(argv: list[str] | None = None) -> int:
    """The command line: ``speed``, ``phases``; returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m analysis.benchmarks.bench_ppo",
                                     description=bench_ppo.__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    speed_p = sub.add_parser("speed", help="env steps per second of single iterations, one variant after another")
    speed_p.add_argument("variants", nargs="+", choices=SPEED_VARIANTS)
    speed_p.add_argument("--rollouts", type=int, default=4, help="iterations per variant (the first is not timed)")
    speed_p.add_argument("--repeats", type=int, default=1,
                         help="times the whole list of variants runs, one fresh process each (intervals from 2)")
    speed_p.add_argument("--out", type=Path, default=None, help="also write the table to this markdown file")
    phases_p = sub.add_parser("phases", help="where one iteration's time goes, per variant")
    phases_p.add_argument("variants", nargs="+", choices=SPEED_VARIANTS)
    phases_p.add_argument("--rollouts", type=int, default=3, help="iterations per variant (the first is not timed)")
    phases_p.add_argument("--out", type=Path, default=None, help="also write the table to this markdown file")
    args = parser.parse_args(argv)
    if args.rollouts < 2:
        parser.error(f"--rollouts must be at least 2 (the first is not timed), got {args.rollouts}")
    if args.command == "speed" and args.repeats < 1:
        parser.error(f"--repeats must be at least 1, got {args.repeats}")
    table = (speed(args.variants, args.rollouts, args.repeats) if args.command == "speed"
             else phases(args.variants, args.rollouts))
    sys.stdout.write(table)
    if args.out is not None:
        arguments = argv if argv is not None else sys.argv[1:]
        command = " ".join(["python -m analysis.benchmarks.bench_ppo", *arguments])
        title = "Speed of one PPO iteration" if args.command == "speed" else "Where one PPO iteration's time goes"
        args.out.write_text(f"# {title}\n\nWritten by `{command}` on {time.strftime('%Y-%m-%d')} "
                            f"({os.cpu_count()} cores; iterations 2-{args.rollouts}).\n\n{table}")
    return 0
