"""GIF of a ball-catching policy from a sweep, run without exploration (``tanh(Θ x)``).

Reads the ``summary.json`` files under the given sweep directories (shards too), ranks the runs
of the chosen explorer and estimator by their final deterministic evaluation, picks the best
(``--pick best``) or the median one (``--pick median``: a typical run), replays its final ``Θ``
on the job's arm in the gymnasium env with pybullet's software renderer and writes a GIF (every
5th frame). Prints one JSON line: the run, its final evaluation and the return of the filmed
episode, both as mean rewards per step (the paper's units).

Usage:
    python -m analysis.paper.ballcatch_video --out docs/study/ballcatch/sde_best.gif SWEEP_DIR [more shards...]
    python -m analysis.paper.ballcatch_video --explorer rex --pick median \
        --out docs/study/ballcatch/rex_typical.gif SWEEP_DIR
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np

from analysis.sweeps import finished_jobs
from sde_torchrl.envs.ballcatch import BallCatchEnv, episode_return
from sde_torchrl.envs.ballcatch.demo import write_gif
from sde_torchrl.trainers.summary import mean_reward_factor

WEIGHTS = ("module.0.module.0.module.weight", "module.0.module.weight")
"""The linear controller's ``Θ`` in the policy's state dict (``summary.json: final_parameters``):
under ``make_sde_actor`` (0.3 on), or under ``TensorDictSequential(actor, explorer)`` (the
committed runs made before, and PGPE)."""


class Run(NamedTuple):
    """One trained run: global index, final deterministic return (mean reward), ``Θ [4, 3]``, arm."""

    index: int
    final: float
    theta: np.ndarray
    model: str


def find_runs(directories: list[Path], explorer: str, estimator: str) -> list[Run]:
    """The runs of ``explorer`` with ``estimator`` under ``directories``."""
    runs = []
    for job in finished_jobs(*directories):
        summary = job.summary
        if [summary.get(key) for key in ("explorer", "estimator", "env")] != [explorer, estimator, "ballcatch"]:
            continue
        scale = mean_reward_factor(summary)
        model = job.config["env"].get("model", "cup")  # summaries without it predate the choice
        weights = next(summary["final_parameters"][name] for name in WEIGHTS if name in summary["final_parameters"])
        for offset, final in enumerate(summary["final_eval_return"]):
            theta = np.asarray(weights[offset], dtype=np.float64).reshape(4, 3)
            runs.append(Run(summary["first_run"] + offset, scale * final, theta, model))
    if not runs:
        raise SystemExit(f"error: no {explorer}/{estimator} ball-catching runs under {[str(d) for d in directories]}")
    return runs


def pick(runs: list[Run], which: str) -> Run:
    """The run with the best final return (the lowest index among equals), or the median one
    (the lower median of the final returns)."""
    ranked = sorted(runs, key=lambda run: (run.final, -run.index))
    return ranked[-1] if which == "best" else ranked[(len(ranked) - 1) // 2]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sweeps", nargs="+", type=Path, help="sweep or run directories (shards)")
    parser.add_argument("--out", type=Path, required=True, help="GIF file to write")
    parser.add_argument("--explorer", default="sde")
    parser.add_argument("--estimator", default="reinforce")
    parser.add_argument("--pick", choices=("best", "median"), default="best",
                        help="the run with the best or the median final evaluation")
    parser.add_argument("--seed", type=int, default=0, help="reset seed of the filmed episode")
    args = parser.parse_args(argv)
    run = pick(find_runs(args.sweeps, args.explorer, args.estimator), args.pick)
    env, frames = BallCatchEnv(render_mode="rgb_array", model=run.model), []
    try:
        filmed = episode_return(env, lambda obs: np.tanh(run.theta @ np.asarray(obs, dtype=np.float64)), args.seed,
                                frames=frames)
    finally:
        env.close()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_gif(frames, args.out)
    print(json.dumps({"explorer": args.explorer, "estimator": args.estimator, "pick": args.pick, "run": run.index,
                      "model": run.model, "final_eval_return": round(run.final, 4),
                      "filmed_return": round(filmed, 4), "theta": np.round(run.theta, 3).tolist(),
                      "gif": str(args.out)}))


if __name__ == "__main__":
    sys.exit(main())
