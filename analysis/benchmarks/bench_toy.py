"""Env steps per second on the 1-D minimisation task: a plain loop against the batched path.

(a) ``plain``: one run, one env, TorchRL's ``env.rollout`` stepping a single episode at a time
    (a Python loop per step), then the estimator and the update: the straightforward way.
(b) ``batched``: what ``analysis/paper/table1.py`` runs: ``runs`` learners side by side, each with
    ``episodes`` episodes per update, collected by :func:`sde_torchrl.collectors.rollout.tensor_rollout`.

Both count full training updates (collect, estimate, step), so the figures are what a sweep gets.

Usage:
    python -m analysis.benchmarks.bench_toy [--runs 30] [--episodes 10] [--length 15] [--seconds 5]
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from sde_torchrl.config.build import build_trainer
from sde_torchrl.config.compose import compose


def steps_per_second(overrides: list[str], seconds: float) -> float:
    """Env steps per second of whole training updates for the composed config."""
    cfg = compose(["+experiment=minimize", "logger=none", *overrides])
    trainer = build_trainer(cfg)
    trainer.estimate(trainer.collect(), 0)  # warm-up
    steps_per_update = cfg.runs * cfg.episodes_per_update * cfg.env.episode_length
    updates, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        trainer.estimate(trainer.collect(), updates)
        updates += 1
    return updates * steps_per_update / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=30)
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--length", type=int, default=15)
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    length = f"env.episode_length={args.length}"
    # episode_queue=2 only passes the config check (REINFORCE on one episode learns nothing, so
    # a job is refused): steps_per_second calls collect and update itself, one episode at a time.
    plain = steps_per_second(["runs=1", "episodes_per_update=1", "episode_queue=2", length, "tensor_rollout=false"],
                             args.seconds)
    batched = steps_per_second([f"runs={args.runs}", f"episodes_per_update={args.episodes}", length],
                               args.seconds)
    print(json.dumps({
        "plain_steps_per_s": round(plain), "batched_steps_per_s": round(batched),
        "ratio": round(batched / plain, 1), "runs": args.runs, "episodes_per_update": args.episodes,
        "episode_length": args.length, "threads": torch.get_num_threads(),
    }))


if __name__ == "__main__":
    main()
