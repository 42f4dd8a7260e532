"""GIF of the best policy of a ball-catching sweep, run without exploration (``tanh(Θ x)``).

Reads the ``summary.json`` files under the given sweep directories (shards too), picks the run
of the chosen explorer and estimator whose final deterministic evaluation was best, replays its
final ``Θ`` in the gymnasium env with pybullet's software renderer and writes a GIF (every 5th
frame). Prints one JSON line: the run, its final evaluation and the return of the filmed episode.

Usage:
    python analysis/ballcatch_video.py --out docs/ballcatch_sde_best.gif SWEEP_DIR [more shards...]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from sde_torchrl.envs.ballcatch import BallCatchEnv, episode_return
from sde_torchrl.envs.ballcatch.demo import write_gif
from sde_torchrl.run_dir import read_summary

WEIGHT = "module.0.module.weight"
"""The linear controller's ``Θ`` in the policy's state dict (``summary.json: final_parameters``)."""


def best_run(directories: list[Path], explorer: str, estimator: str) -> tuple[int, float, np.ndarray]:
    """``(global run index, final deterministic return, Θ [4, 3])`` of the best run."""
    best: tuple[int, float, np.ndarray] | None = None
    for directory in directories:
        for path in sorted(directory.rglob("summary.json")):
            summary = read_summary(path)
            if (summary.get("explorer"), summary.get("estimator"), summary.get("env")) != (
                    explorer, estimator, "ballcatch"):
                continue
            weights = summary["final_parameters"][WEIGHT]
            for offset, final in enumerate(summary["final_eval_return"]):
                if best is None or final > best[1]:
                    theta = np.asarray(weights[offset], dtype=np.float64).reshape(4, 3)
                    best = (summary["first_run"] + offset, final, theta)
    if best is None:
        raise SystemExit(f"error: no {explorer}/{estimator} ball-catching runs under {[str(d) for d in directories]}")
    return best


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sweeps", nargs="+", type=Path, help="sweep or run directories (shards)")
    parser.add_argument("--out", type=Path, required=True, help="GIF file to write")
    parser.add_argument("--explorer", default="sde")
    parser.add_argument("--estimator", default="reinforce")
    parser.add_argument("--seed", type=int, default=0, help="reset seed of the filmed episode")
    args = parser.parse_args(argv)
    run, final, theta = best_run(args.sweeps, args.explorer, args.estimator)
    env, frames = BallCatchEnv(render_mode="rgb_array"), []
    try:
        filmed = episode_return(env, lambda obs: np.tanh(theta @ np.asarray(obs, dtype=np.float64)), args.seed,
                                frames=frames)
    finally:
        env.close()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_gif(frames, args.out)
    print(json.dumps({"explorer": args.explorer, "estimator": args.estimator, "run": run,
                      "final_eval_return": round(final, 4), "filmed_return": round(filmed, 4),
                      "theta": np.round(theta, 3).tolist(), "gif": str(args.out)}))


if __name__ == "__main__":
    sys.exit(main())
