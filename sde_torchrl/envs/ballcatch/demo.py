"""Demo and GIF command line of the ball-catching task: ``python -m sde_torchrl.envs.ballcatch``.

Runs a few episodes of the scripted, zero or random policy in the gymnasium env and prints one
JSON line with the returns, e.g. ``python -m sde_torchrl.envs.ballcatch --policy scripted
--episodes 5`` (``--model cup`` for the second arm, ``--video out.gif`` for a GIF of the
first episode).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sde_torchrl.envs.ballcatch.gym_env import BallCatchEnv, episode_return
from sde_torchrl.envs.ballcatch.models import ARM_MODELS
from sde_torchrl.envs.ballcatch.world import BallCatchConfig

__all__ = ["main", "write_gif"]


def write_gif(frames: Sequence[np.ndarray], path: str | Path, fps: int = 20) -> None:
    """Write RGB frames to an animated GIF with pillow.

    Examples:
        >>> import tempfile
        >>> frames = [np.full((4, 4, 3), c, dtype=np.uint8) for c in (0, 255)]
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     write_gif(frames, Path(tmp) / "blink.gif")
    """
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0, optimize=True)


def main(argv: Sequence[str] | None = None) -> None:
    """CLI demo: run a few episodes and print one JSON line with the returns.

    Examples:
        >>> main(["--policy", "zero", "--episodes", "1", "--model", "pybrain"])
        {"model": "pybrain", "policy": "zero", "episodes": 1, "seed": 0, "returns": [-2.3329], "mean_return": -2.3329}
    """
    parser = argparse.ArgumentParser(description="Ball-catching demo (paper section 4.2) in pybullet.")
    parser.add_argument("--policy", choices=("scripted", "zero", "random"), default="scripted")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0, help="episode i uses seed + i")
    parser.add_argument("--jitter", type=float, default=BallCatchConfig.jitter)
    parser.add_argument("--model", choices=tuple(ARM_MODELS), default=BallCatchConfig.model, help="the arm")
    parser.add_argument("--video", type=str, default=None, help="write the first episode to this GIF")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error("--episodes must be >= 1")
    config = BallCatchConfig(jitter=args.jitter, model=args.model)
    env = BallCatchEnv(render_mode="rgb_array" if args.video else None, config=config)
    rng = np.random.default_rng(args.seed)
    returns, frames = [], [] if args.video else None
    try:
        for i in range(args.episodes):
            returns.append(episode_return(env, args.policy, args.seed + i, rng, frames if i == 0 else None))
    finally:
        env.close()
    if args.video:
        write_gif(frames, args.video)
    out = {
        "model": args.model,
        "policy": args.policy,
        "episodes": args.episodes,
        "seed": args.seed,
        "returns": [round(r, 4) for r in returns],
        "mean_return": round(float(np.mean(returns)), 4),
    }
    print(json.dumps(out))

