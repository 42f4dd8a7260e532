"""The deterministic evaluation of each run's initial controller ``Θ0`` in a ball-catching job.

What Fig. 5's curves start from, and what "the mean final evaluation is above the mean initial
one" compares with (the trainer's first evaluation comes after ``eval_period`` updates). Builds
the job that ``train.py OVERRIDES`` would run, trains nothing, evaluates ``Θ0`` as the trainer
evaluates (``eval_episodes`` episodes per run without exploration, the job's evaluation env)
and writes ``initial.json``: the job's explorer, estimator, first run and each run's return as
a mean reward per step (the paper's units). ``analysis/paper/fig5.py`` finds these files under the
sweep directories it reads.

Usage:
    python -m analysis.paper.ballcatch_initial --out SWEEP/initial_rex +experiment=ballcatch_paper_sweep explorer=rex \
        first_run=0
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sde_torchrl.config.build import build_trainer
from sde_torchrl.config.compose import compose
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.trainers.summary import per_step_factor


def initial_evaluation(overrides: list[str]) -> dict:
    """The job's labels and each run's deterministic return of ``Θ0`` (mean reward per step)."""
    choices = compose(overrides, return_hydra_config=True).hydra.runtime.choices
    conf = validate(compose(overrides))
    trainer = build_trainer(conf)
    try:
        returns = trainer.evaluate()
    finally:
        trainer.close()
    scale = per_step_factor(conf.estimator.episode_return, conf.env.episode_length)
    return {"explorer": choices.explorer, "estimator": choices.estimator, "overrides": overrides,
            "first_run": conf.first_run, "initial_eval_return": (scale * returns).tolist()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="directory to write initial.json into")
    parser.add_argument("overrides", nargs="+", help="the job's Hydra overrides, as for train.py")
    args = parser.parse_args(argv)
    result = initial_evaluation(args.overrides)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "initial.json").write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
