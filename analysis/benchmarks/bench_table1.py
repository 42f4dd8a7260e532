"""Where a Table 1 update's time goes: collection against estimation and step, per sweep cell.

Regenerating Table 1 (``python -m analysis.paper.table1``) is mostly its REX jobs, each up to
2,000 updates of 30 runs × 10 episodes. This times those updates as the job makes them, in one
process on one thread, for each cell given: ``collect_ms``, the episodes of one update by the fast
path the trainer takes (:func:`sde_torchrl.collectors.rollout.collect_episodes`), and
``update_ms``, the estimator and the optimiser step on them (``Trainer.update``: the scores, the
gradient, the guards), update after update as the job makes them (``--updates`` of the job's
2,000 at most). Medians over ``--repeats`` blocks of ``--updates`` updates each.

Prints ONE JSON line: per cell (``explorer`` at ``episode_length``) its ``collect_ms``,
``update_ms`` and ``steps_per_update`` (runs × episodes × steps). ``--scores autograd`` times the
updates with autograd's scores in place of the closed form the sweeps use.

Usage:
    python -m analysis.benchmarks.bench_table1 [--lengths 45 15] [--explorers rex sde] [--updates 100]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time

import torch

from sde_torchrl.config.build import build_trainer
from sde_torchrl.config.compose import compose


def time_cell(explorer: str, length: int, updates: int, repeats: int, scores: str | None = None) -> dict[str, float]:
    """Median milliseconds per update of collection and of estimation and step, for the
    ``episode_length_sweep`` job of ``explorer`` at ``length`` (its scores computed as ``scores``
    says, else as the experiment sets)."""
    cfg = compose(["+experiment=episode_length_sweep", f"env.episode_length={length}", f"explorer={explorer}",
                   "logger=none", *([f"scores={scores}"] if scores else [])])
    trainer = build_trainer(cfg, tempfile.mkdtemp())
    trainer.estimate(trainer.collect(), 0)  # warm-up
    collect, update, k = [], [], 1
    for _ in range(repeats):  # the job's own sequence of updates, each on fresh episodes
        collected = stepped = 0.0
        for _ in range(updates):
            start = time.perf_counter()
            episodes = trainer.collect()
            middle = time.perf_counter()
            trainer.estimate(episodes, k)
            collected, stepped, k = collected + middle - start, stepped + time.perf_counter() - middle, k + 1
        collect.append(collected / updates)
        update.append(stepped / updates)
    trainer.close()
    return {"collect_ms": round(1e3 * statistics.median(collect), 3),
            "update_ms": round(1e3 * statistics.median(update), 3),
            "steps_per_update": cfg.runs * cfg.episodes_per_update * length}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--lengths", type=int, nargs="+", default=[45, 15], help="episode lengths (EL)")
    parser.add_argument("--explorers", nargs="+", default=["rex", "sde"], choices=["rex", "sde"])
    parser.add_argument("--updates", type=int, default=100, help="updates per timed block")
    parser.add_argument("--repeats", type=int, default=3, help="timed blocks; the median is printed")
    parser.add_argument("--scores", choices=["autograd", "closed_form"],
                        help="how the scores are computed (default: as the experiment sets, closed_form)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    cells = {f"{explorer}_el{length}": time_cell(explorer, length, args.updates, args.repeats, args.scores)
             for explorer in args.explorers for length in args.lengths}
    print(json.dumps({"cells": cells, "scores": args.scores or "closed_form", "updates": args.updates,
                      "repeats": args.repeats, "threads": torch.get_num_threads(), "torch": torch.__version__}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
