"""Films the best policy of a finished ball-catching job: the run whose best policy did best on
the job's fresh balls (``best_check_return`` in its ``summary.json``), its parameters from the
job's ``best_policy.pt``, on another fresh ball, as a GIF.

The job's policy is rebuilt for that run alone (its config recomposed from ``.hydra/overrides.yaml``
and checked against what the job recorded, :func:`analysis.paper.ballcatch_final.rebuilt_config`),
so filming a 50-run job does not build its 200 simulator worlds.

Usage:
    python -m analysis.paper.ballcatch_best_film results/ballcatch/runs/checked/sde \
        --out docs/study/ballcatch/checked/best_policy.gif
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from analysis.paper.ballcatch_final import rebuilt_config
from analysis.sweeps import EXIT_REFUSED, finished_jobs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__.splitlines()[0])
    parser.add_argument("sweep", type=Path, help="a sweep or run directory of finished ball-catching jobs")
    parser.add_argument("--out", type=Path, required=True, help="the GIF to write")
    args = parser.parse_args(argv)
    import torch

    from sde_torchrl.config.build import build_trainer
    from sde_torchrl.config.schemas.train import validate
    from sde_torchrl.trainers.best import BEST_POLICY
    from sde_torchrl.trainers.trainer import film_policy

    jobs = [job for job in finished_jobs(args.sweep) if "best_check_return" in job.summary]
    if not jobs or not all((job.path / BEST_POLICY).is_file() for job in jobs):
        print(f"error: {args.sweep} holds no finished job with a final check and its {BEST_POLICY}", file=sys.stderr)
        return EXIT_REFUSED
    job, run = max(((job, r) for job in jobs for r in range(job.summary["runs"])),
                   key=lambda pair: pair[0].summary["best_check_return"][pair[1]])
    summary, first = job.summary, job.summary["first_run"]
    trainer = build_trainer(validate(rebuilt_config(job, {"runs": 1, "first_run": first + run, "logger": "none"})))
    try:
        state = torch.load(job.path / BEST_POLICY, weights_only=True)["state_dict"]
        runs = summary["runs"]
        trainer.policy.load_state_dict({name: value[run:run + 1] if value.dim() and value.shape[0] == runs else value
                                        for name, value in state.items()})
        args.out.parent.mkdir(parents=True, exist_ok=True)
        filmed = film_policy(trainer.policy, trainer.eval_env, 0, args.out, seed=first + run)
    finally:
        trainer.close()
    print(json.dumps({"job": str(job.path), "run": first + run, "best_update": summary["best_update"][run],
                      "best_check_mean_reward": round(summary["best_check_mean_reward"][run], 4),
                      "filmed_mean_reward": round(filmed, 4), "gif": str(args.out)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
