"""The PPO benchmark's command line (``python -m analysis.benchmarks.bench_ppo``)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from analysis.benchmarks import bench_ppo
from analysis.benchmarks.bench_ppo.build import METHODS
from analysis.benchmarks.bench_ppo.report import report
from analysis.benchmarks.bench_ppo.speed import SPEED_VARIANTS, phases, speed
from analysis.benchmarks.bench_ppo.train import run


def main(argv: list[str] | None = None) -> int:
    """The command line: ``run``, ``speed``, ``phases``, ``report``; returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m analysis.benchmarks.bench_ppo",
                                     description=bench_ppo.__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run_p = sub.add_parser("run", help="train one method with one seed")
    run_p.add_argument("--method", choices=METHODS, required=True)
    run_p.add_argument("--seed", type=int, default=0)
    run_p.add_argument("--steps", type=int, default=500_000)
    run_p.add_argument("--out", type=Path, default=Path("results/ppo/runs"))
    run_p.add_argument("--compile", action="store_true",
                       help="torch.compile the whole TorchRL update (loss, backward, clip, Adam)")
    run_p.add_argument("--unclipped-actions", action="store_true",
                       help="ablation: step the TorchRL env with the sampled, unclipped action")
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
    rep_p = sub.add_parser("report", help="table and plot from a folder of runs")
    rep_p.add_argument("folder", type=Path)
    rep_p.add_argument("--out", type=Path, default=Path("docs/ppo"))
    args = parser.parse_args(argv)
    if args.command == "run":
        if args.steps <= 0:
            parser.error(f"--steps must be positive, got {args.steps}")
        if (args.compile or args.unclipped_actions) and args.method.startswith("sb3"):
            parser.error("--compile and --unclipped-actions apply to the TorchRL methods (plain, sde), not to SB3")
        path = run(args.method, args.seed, args.steps, args.out, args.compile, not args.unclipped_actions)
        data = json.loads(path.read_text())
        print(f"{args.method} seed {args.seed}: final return {data['final_return_mean']:.1f}, "
              f"{data['env_steps_per_s']:.0f} env steps/s, {data['wall_s']:.0f} s -> {path}")
    elif args.command in ("speed", "phases"):
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
    else:
        sys.stdout.write(report(args.folder, args.out))
    return 0

