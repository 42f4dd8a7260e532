"""The final policy of every run of a ball-catching sweep, evaluated on more episodes.

The trainer's final evaluation is a few deterministic episodes (3 in the paper); for a run whose
policy catches some balls and drops others, whether that one evaluation counts as a catch is
partly a draw. This evaluates each run's final controller again, on ``--episodes`` episodes of
the evaluation env's streams under ``--seed``, by the trainer's own path: the job's config
(recomposed from its ``.hydra/overrides.yaml`` and checked against the config its summary
records), its policy with ``final_parameters`` from ``summary.json`` loaded, ``Trainer.evaluate``
without exploration. Run ``r``'s episodes depend only on the seed and ``r`` (the per-run
streams), so every method is evaluated on the same balls, and a job is evaluated ``--chunk``
runs at a time (each run's episodes are simulator worlds: 50 runs × 20 episodes at once would
need about 28 GB) with the same result.

Writes ``final_policy.json`` into each job directory: the job's explorer, estimator, first run,
the episodes and seed, and each run's return as a mean reward per step (the paper's units).
``analysis/paper/fig5.py`` reports the counts beside the trainer's when every run has one. The rule
that fixed ``--episodes 20 --seed 7`` before any run: ``docs/study/ballcatch/final_policy_rule.md``.

With ``--model NAME`` the same policies are evaluated in another arm model (``pybrain_held``: the
arm joints held level, a diagnostic) and with their behaviour per episode
(:func:`~sde_torchrl.envs.ballcatch.outcomes.catch_outcomes`), into ``reevaluation_NAME.json``
(rule: ``docs/study/ballcatch/reevaluation_rule.md``).

Usage:
    python -m analysis.paper.ballcatch_final --episodes 20 --seed 7 results/ballcatch/runs/fig5_selected/sde
    python -m analysis.paper.ballcatch_final --episodes 20 --seed 7 --model pybrain_held \
        results/ballcatch/runs/fig5_selected/sde
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import torch
import yaml
from omegaconf import OmegaConf

from analysis.sweeps import finished_jobs
from sde_torchrl.config.build import build_trainer
from sde_torchrl.config.compose import compose
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.envs.ballcatch.models import ARM_MODELS
from sde_torchrl.envs.ballcatch.outcomes import catch_outcomes
from sde_torchrl.jobs.checkpoint import config_differences, result_config
from sde_torchrl.jobs.run_dir import FinishedRun
from sde_torchrl.trainers.summary import mean_reward_factor

log = logging.getLogger("ballcatch_final")

#: What the re-evaluation changes in a job's config; everything else must be as the job ran.
CHANGED = ("runs", "first_run", "eval_episodes", "seed", "logger")


def job_overrides(job: FinishedRun) -> list[str]:
    """The Hydra overrides the job was launched with (its ``.hydra/overrides.yaml``)."""
    path = job.path / ".hydra" / "overrides.yaml"
    if not path.is_file():
        raise SystemExit(f"error: {path} is missing: the job's overrides are needed to rebuild its policy")
    return list(yaml.safe_load(path.read_text()) or [])


def rebuilt_config(job: FinishedRun, changes: dict[str, object]) -> object:
    """The job's config with ``changes``, refused if anything else differs from what the job ran
    with (the config tree changed since)."""
    cfg = compose([*job_overrides(job), *(f"{key}={value}" for key, value in changes.items())])
    current = result_config(OmegaConf.to_container(cfg, resolve=True))
    saved = result_config(job.config)
    changed = (*CHANGED, *changes)
    differences = [line for line in config_differences(saved, current) if line.split(":")[0] not in changed]
    if differences:
        raise SystemExit(f"error: {job.path}: the config tree no longer rebuilds this job's policy "
                         f"({'; '.join(differences[:3])}); check out the commit the job ran on")
    return cfg


def load_final_parameters(policy: torch.nn.Module, final: dict[str, list], start: int, count: int) -> None:
    """Copies runs ``start .. start + count`` of the summary's ``final_parameters`` into ``policy``'s
    parameters (stacked over runs: each one's first dimension is the run). What is not a parameter
    (a σ̂ the job kept fixed) is what the config builds, as in the job."""
    parameters = dict(policy.named_parameters())
    mismatched = sorted(set(final) ^ set(parameters))
    if mismatched:
        raise SystemExit(f"error: the summary's final_parameters do not match the policy's ({mismatched[:3]}): "
                         "the job was written by another version of the policy")
    with torch.no_grad():
        for name, values in final.items():
            target = parameters[name]
            target.copy_(torch.as_tensor(values[start:start + count], dtype=target.dtype).reshape(target.shape))


def evaluate_job(job: FinishedRun, episodes: int, seed: int, chunk: int, model: str | None = None) -> dict:
    """Each run's final policy of ``job``, evaluated on ``episodes`` episodes under ``seed``; in arm
    ``model`` (``None``: the job's own) with each episode's return and behaviour."""
    summary = job.summary
    runs, first = summary["runs"], summary["first_run"]
    returns: list[float] = []
    per_episode: dict[str, list] = {}
    for start in range(0, runs, chunk):
        count = min(chunk, runs - start)
        changes = {"runs": count, "first_run": first + start, "eval_episodes": episodes, "seed": seed, "logger": "none"}
        cfg = rebuilt_config(job, changes if model is None else {**changes, "env.model": model})
        trainer = build_trainer(validate(cfg))
        try:
            load_final_parameters(trainer.policy, summary["final_parameters"], start, count)
            evaluation = trainer.evaluation_episodes()
            returns += trainer.estimator.returns(evaluation).mean(-1).tolist()
            if model is not None:
                for key, values in episode_outcomes(evaluation, trainer, mean_reward_factor(summary)).items():
                    per_episode.setdefault(key, []).extend(values)
        finally:
            trainer.close()
        log.info("%s: runs %d-%d evaluated", job.path, first + start, first + start + count - 1)
    scale = mean_reward_factor(summary)
    result = {"explorer": summary["explorer"], "estimator": summary["estimator"], "first_run": first,
              "episodes": episodes, "seed": seed, "final_policy_return": [scale * value for value in returns]}
    return result if model is None else {**result, "model": model, "per_episode": per_episode}


def episode_outcomes(episodes, trainer, scale: float) -> dict[str, list]:
    """Per run, each evaluation episode's return (mean reward per step) and behaviour
    (:func:`~sde_torchrl.envs.ballcatch.outcomes.catch_outcomes`), as lists ``[runs][episodes]``."""
    env = trainer.eval_env.base_env
    observed = torch.cat([episodes["observation"][..., :1, :], episodes["next", "observation"]], -2)
    ball = env.ball_positions(observed)  # a scaled observation is not the ball's position
    reward = episodes["next", "reward"][..., 0]
    ground_z = env.config.arm.ground_z
    outcomes = catch_outcomes(ball, episodes["action"][..., 3], reward, ground_z)
    outcomes["return"] = scale * trainer.estimator.returns(episodes)
    return {key: value.tolist() for key, value in outcomes.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sweeps", nargs="+", type=Path, help="sweep or run directories (shards)")
    parser.add_argument("--episodes", type=int, required=True, help="deterministic episodes per run")
    parser.add_argument("--seed", type=int, required=True, help="seed of the evaluation env's streams")
    parser.add_argument("--chunk", type=int, default=10, help="runs evaluated at once (memory)")
    parser.add_argument("--force", action="store_true", help="evaluate jobs that already have the file")
    parser.add_argument("--model", choices=list(ARM_MODELS),
                        help="evaluate in this arm, with each episode's behaviour, into reevaluation_MODEL.json")
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.chunk < 1:
        parser.error("--episodes and --chunk must be at least 1")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    jobs = finished_jobs(*args.sweeps)
    if not jobs:
        parser.error(f"no finished jobs under {[str(s) for s in args.sweeps]}")
    for job in jobs:
        out = job.path / ("final_policy.json" if args.model is None else f"reevaluation_{args.model}.json")
        if out.is_file() and not args.force:
            found = json.loads(out.read_text())
            if (found["episodes"], found["seed"]) != (args.episodes, args.seed):
                parser.error(f"{out} holds {found['episodes']} episodes on seed {found['seed']}: "
                             "pass --force to replace it")
            continue
        result = evaluate_job(job, args.episodes, args.seed, args.chunk, args.model)
        out.write_text(json.dumps(result, indent=1))
        catches = sum(value >= -1.1 for value in result["final_policy_return"])
        log.info("%s: %d of %d final policies catch (R >= -1.1 over %d episodes); wrote %s", job.path, catches,
                 len(result["final_policy_return"]), args.episodes, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
