"""The SAC benchmark's command line (``python -m analysis.benchmarks.bench_sac``)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from analysis.benchmarks import bench_sac
from analysis.benchmarks.bench_sac.build import ENVS, LOSS_NOISE, METHODS, ZOO
from analysis.benchmarks.bench_sac.report import report
from analysis.benchmarks.bench_sac.speed import SPEED_VARIANTS, WARM_UP, speed
from analysis.benchmarks.bench_sac.train import run
from analysis.benchmarks.bench_sac.update_speed import update_speed
from analysis.benchmarks.common import EVAL_EPISODES


def main(argv: list[str] | None = None) -> int:
    """Command line: ``run`` one training, ``report`` a folder of runs."""
    parser = argparse.ArgumentParser(prog="python -m analysis.benchmarks.bench_sac",
                                     description=bench_sac.__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run_p = sub.add_parser("run", help="train one method with one seed on one env")
    run_p.add_argument("--method", choices=METHODS, required=True)
    run_p.add_argument("--env", choices=ENVS, default="mountaincar")
    run_p.add_argument("--seed", type=int, default=0)
    run_p.add_argument("--steps", type=int, default=None, help="env steps (default: the zoo's n_timesteps)")
    run_p.add_argument("--out", type=Path, default=Path("results/sac/runs"))
    run_p.add_argument("--learning-starts", type=int, default=None,
                       help="replace the zoo's learning_starts on both sides (short budgets)")
    run_p.add_argument("--eval-episodes", type=int, default=EVAL_EPISODES, help="deterministic episodes at the end")
    run_p.add_argument("--loss-noise", choices=LOSS_NOISE, default="fresh",
                       help="SDE noise of the SAC losses: a fresh matrix per gradient step (SB3) or the stored ξ")
    run_p.add_argument("--compile", action="store_true",
                       help="torch.compile the whole TorchRL gradient step (losses, backward passes, Adam, target)")
    run_p.add_argument("--compile-policy", action="store_true",
                       help="with --compile, also compile the collector's policy (Collector(compile_policy=True))")
    speed_p = sub.add_parser("update-speed", help="ms per gradient step of each method, interleaved in one process")
    speed_p.add_argument("--env", choices=ENVS, default="mountaincar")
    speed_p.add_argument("--updates", type=int, default=100, help="gradient steps per timing")
    speed_p.add_argument("--rounds", type=int, default=3, help="timed rounds (after one warm-up round)")
    speed_p.add_argument("--profile", action="store_true", help="split the TorchRL SDE step by function")
    speed_p.add_argument("--compile", action="store_true", help="also time the compiled TorchRL SDE step")
    speed_p.add_argument("--out", type=Path, default=None, help="also write the tables to this markdown file")
    round_p = sub.add_parser("speed", help="env steps per second of train.py's SAC job and SB3's, fresh processes")
    round_p.add_argument("variants", nargs="+", choices=SPEED_VARIANTS)
    round_p.add_argument("--rounds", type=int, default=30, help=f"rounds per process (the first {WARM_UP} not timed)")
    round_p.add_argument("--repeats", type=int, default=1, help="times the whole list of variants runs")
    round_p.add_argument("--out", type=Path, default=None, help="also write the table to this markdown file")
    rep_p = sub.add_parser("report", help="tables and plot from a folder of runs")
    rep_p.add_argument("folder", type=Path)
    rep_p.add_argument("--out", type=Path, default=Path("docs/sac"))
    args = parser.parse_args(argv)
    import logging

    import torchrl  # noqa: F401  (sets its logger up; then quieten it: its INFO lines go to stdout)

    logging.getLogger("torchrl").setLevel(logging.WARNING)
    if args.command == "run":
        steps = ZOO[args.env]["n_timesteps"] if args.steps is None else args.steps
        if steps <= 0:
            parser.error(f"--steps must be positive, got {steps}")
        if args.eval_episodes <= 0:
            parser.error(f"--eval-episodes must be positive, got {args.eval_episodes}")
        if args.loss_noise != "fresh" and args.method != "sde":
            parser.error("--loss-noise applies to the TorchRL SDE method (sde) only")
        if args.compile and args.method.startswith("sb3"):
            parser.error("--compile applies to the TorchRL methods (sde, plain), not to SB3")
        if args.compile and args.loss_noise != "fresh":
            parser.error("--compile runs the fresh loss noise only; drop --loss-noise stored or --compile")
        if args.compile_policy and not args.compile:
            parser.error("--compile-policy goes with --compile (the update compiled too)")
        if args.learning_starts is not None and not 0 <= args.learning_starts < steps:
            parser.error(f"--learning-starts must be in [0, steps), got {args.learning_starts}")
        overrides = {} if args.learning_starts is None else {"learning_starts": args.learning_starts}
        path = run(args.method, args.env, args.seed, steps, args.out, args.loss_noise, args.eval_episodes, overrides,
                   args.compile, args.compile_policy)
        data = json.loads(path.read_text())
        print(f"{args.env} {args.method} seed {args.seed}: final return {data['final_return_mean']:.1f}, "
              f"{data['env_steps_per_s']:.0f} env steps/s, {data['wall_s']:.0f} s -> {path}")
    elif args.command == "update-speed":
        if args.updates <= 0 or args.rounds <= 0:
            parser.error(f"--updates and --rounds must be positive, got {args.updates} and {args.rounds}")
        page = update_speed(args.env, args.updates, args.rounds, args.profile, args.compile)
        if args.out is not None:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text("Generated by `python -m analysis.benchmarks.bench_sac update-speed "
                                f"--env {args.env} --updates "
                                f"{args.updates} --rounds {args.rounds}{' --profile' if args.profile else ''}"
                                f"{' --compile' if args.compile else ''}`.\n\n"
                                + page)
        sys.stdout.write(page)
    elif args.command == "speed":
        if args.rounds < WARM_UP + 2 or args.repeats < 1:
            parser.error(f"--rounds must be at least {WARM_UP + 2} and --repeats at least 1, "
                         f"got {args.rounds} and {args.repeats}")
        table = speed(args.variants, args.rounds, args.repeats)
        if args.out is not None:
            arguments = argv if argv is not None else sys.argv[1:]
            command = " ".join(["python -m analysis.benchmarks.bench_sac", *arguments])
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(f"Written by `{command}` on {time.strftime('%Y-%m-%d')} ({os.cpu_count()} cores).\n\n"
                                + table)
        sys.stdout.write(table)
    else:
        sys.stdout.write(report(args.folder, args.out))
    return 0

