"""Ball catching: does closing the hand raise a controller's exploratory return, and does each
estimator's 20-episode estimate point that way?

For every final controller ``u = tanh(Θ x)`` of a linear SDE sweep (``Θ`` and ``σ̂`` from each
job's ``summary.json``) this simulates, in the shipped arm:

* **the truth**: the derivative of the exploratory mean return along the closing direction ``u``
  (:func:`closing_direction`: it raises the finger command's pre-activation at a ball resting
  against the fingers by exactly its step and leaves it unchanged at the release), by central
  differences with common random numbers (the same draws of ``Θ̂`` and the same balls on both sides);
* **the estimators**: the same exploratory episodes at ``Θ`` in batches of 20 (the episode
  queue's size), each scored as the shipped learner scores them (variance-weighted eq. 16:
  ``Θ̂ Σ_t x_t x_tᵀ``) and handed to REINFORCE (eq. 11 with the optimal per-parameter baseline)
  and ENAC; per batch, whether the estimate raises the finger pre-activation at the rest position;
* **what closing would give**: the deterministic return after steps ``δ u``.

The rule that fixed every number here before any run: ``docs/study/ballcatch/finger_probe_rule.md``.
Each job's result goes to ``finger_probe.json`` in its directory (kept if present, so the page can
be rewritten from committed files); the page to ``finger_probe.md`` and ``finger_probe.json``.

Usage:
    python -m analysis.paper.ballcatch_finger_probe --out docs/study/ballcatch results/ballcatch/runs/fig5_seed3/sde
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import statistics
import sys
from pathlib import Path

import torch

from analysis.figures import write_page_json
from analysis.sweeps import finished_jobs
from sde_torchrl.envs.ballcatch.batched import BatchedBallCatchEnv
from sde_torchrl.envs.ballcatch.outcomes import LEVEL_NAMES, catch_level
from sde_torchrl.envs.ballcatch.world import BallCatchConfig
from sde_torchrl.jobs.run_dir import FinishedRun
from sde_torchrl.modules.sde import sigma_from_param
from sde_torchrl.objectives.estimators import enac_gradient, reinforce_gradient
from sde_torchrl.trainers.summary import mean_reward_factor

log = logging.getLogger("ballcatch_finger_probe")

#: The probe's numbers, fixed by its rule before any run.
REST = (4.0, 0.0, 0.6)  # a ball resting against the fingers of the sunk, tilted palm
RELEASE = (3.5, 0.0, 5.5)  # the ball at its release, above the palm centre
EPISODES, BATCH, STEP = 200, 20, 0.1
DETERMINISTIC_STEPS, DETERMINISTIC_BALLS, DETERMINISTIC_SEED = (0.0, 0.5, 1.0, 2.0), 4, 7
SEED_BASE = 10000
FINGERS = 3  # the finger actuator's row of Θ
REPO = Path(__file__).resolve().parents[2]


def closing_direction(rest: tuple[float, float, float] = REST,
                      release: tuple[float, float, float] = RELEASE) -> torch.Tensor:
    """``u``, shaped like ``Θ`` ``[4, 3]``: in the finger row the shortest ``w`` with
    ``w · x_r = 1`` and ``w · x_s = 0`` (``x_r`` = ``rest``, ``x_s`` = ``release``), zeros
    elsewhere. A step ``δ u`` raises the finger command's pre-activation by ``δ`` with the ball at
    rest and leaves it unchanged at the release and in the other rows.

    Examples:
        >>> u = closing_direction((4.0, 0.0, 0.6), (3.5, 0.0, 5.5))
        >>> points = torch.tensor([[4.0, 3.5], [0.0, 0.0], [0.6, 5.5]], dtype=torch.float64)
        >>> [round(v, 12) for v in (u @ points)[3].tolist()]
        [1.0, 0.0]
        >>> u[:3].abs().sum().item()
        0.0
    """
    points = torch.tensor([rest, release], dtype=torch.float64)  # [2, 3]
    direction = torch.zeros(4, 3, dtype=torch.float64)
    direction[FINGERS] = torch.linalg.pinv(points) @ torch.tensor([1.0, 0.0], dtype=torch.float64)
    return direction


def controller_scores(theta: torch.Tensor, observations: torch.Tensor, samples: torch.Tensor) -> torch.Tensor:
    """The variance-weighted scores of ``Θ`` (eq. 16 times each action's variance ``σ_j²``):
    ``Σ_t (u_t − Θ x_t) x_tᵀ`` per episode, flattened row by row to ``[N, 12]``.

    Args:
        theta: ``Θ`` ``[4, 3]``.
        observations: ``[N, T + 1, 3]``, the ball positions from the reset on.
        samples: ``[N, T, 4]``, the pre-squash actions ``u``.

    Examples:
        >>> theta = torch.zeros(4, 3, dtype=torch.float64)
        >>> x = torch.ones(1, 3, 3, dtype=torch.float64)
        >>> controller_scores(theta, x, torch.ones(1, 2, 4, dtype=torch.float64)).tolist()[0][:3]
        [2.0, 2.0, 2.0]
    """
    x = observations[:, :-1]
    error = samples - x @ theta.T
    return torch.einsum("nta,nts->nas", error, x).flatten(1)


def raises_fingers(gradient: torch.Tensor, rest: tuple[float, float, float] = REST) -> torch.Tensor:
    """Whether each estimate ``[B, 12]`` (``Θ`` row by row) raises the finger pre-activation at
    ``rest`` when followed: ``x_r · g_fingers > 0``.

    Examples:
        >>> g = torch.zeros(2, 12, dtype=torch.float64); g[0, 9], g[1, 11] = 1.0, -1.0
        >>> raises_fingers(g, (1.0, 0.0, 1.0)).tolist()
        [True, False]
    """
    x = torch.tensor(rest, dtype=gradient.dtype)
    return gradient.reshape(-1, 4, 3)[:, FINGERS] @ x > 0


def central_difference(plus: torch.Tensor, minus: torch.Tensor, step: float) -> dict[str, float]:
    """The derivative ``mean(plus − minus) / 2h`` from paired returns, with its 95 % interval
    (normal approximation over the pairs).

    Examples:
        >>> d = central_difference(torch.tensor([1.2, 1.4]), torch.tensor([1.0, 1.0]), 0.1)
        >>> round(d["derivative"], 6), d["low"] < d["derivative"] < d["high"]
        (1.5, True)
    """
    pairs = (plus - minus).double() / (2 * step)
    mean, half = pairs.mean().item(), 1.96 * pairs.std().item() / math.sqrt(len(pairs))
    return {"derivative": mean, "low": mean - half, "high": mean + half}


def closing_pays(derivative: dict[str, float]) -> str:
    """``"pays"``, ``"costs"`` or ``"flat"``: where the derivative's interval lies.

    Examples:
        >>> [closing_pays({"low": lo, "high": hi}) for lo, hi in ((0.1, 0.3), (-0.3, -0.1), (-0.1, 0.1))]
        ['pays', 'costs', 'flat']
    """
    if derivative["low"] > 0:
        return "pays"
    return "costs" if derivative["high"] < 0 else "flat"


def episode_returns(env: BatchedBallCatchEnv, seed: int, maps: torch.Tensor, steps: int) -> tuple[torch.Tensor, ...]:
    """Episodes of the linear controllers ``maps`` ``[N, 4, 3]`` on balls drawn under ``seed``:
    ``(mean reward per step [N], observations, pre-squash actions)`` in float64."""
    env.set_seed(seed)
    observations, samples, rewards = env.linear_episodes(maps, steps)
    return rewards[..., 0].double().mean(-1), observations.double(), samples.double()


def probe_controller(theta: torch.Tensor, sigma: torch.Tensor, seed: int, explore: BatchedBallCatchEnv,
                     evaluate: BatchedBallCatchEnv, steps: int) -> dict:
    """The probe's numbers for one controller ``Θ`` ``[4, 3]`` exploring at ``σ̂`` ``[4, 3]``."""
    generator = torch.Generator().manual_seed(seed)
    noise = torch.randn(EPISODES, 4, 3, generator=generator, dtype=torch.float64) * sigma
    u = closing_direction()
    returns, observations, samples = episode_returns(explore, seed, theta + noise, steps)
    plus, _, _ = episode_returns(explore, seed, theta + STEP * u + noise, steps)
    minus, _, _ = episode_returns(explore, seed, theta - STEP * u + noise, steps)
    scores = controller_scores(theta, observations, samples).reshape(-1, BATCH, 12)
    batch_returns = returns.reshape(-1, BATCH)
    reinforce, _ = reinforce_gradient(scores, batch_returns)
    enac, *_ = enac_gradient(scores, batch_returns)
    balls = DETERMINISTIC_BALLS
    deterministic = [episode_returns(evaluate, DETERMINISTIC_SEED, (theta + delta * u).expand(balls, 4, 3), steps)[0]
                     .mean().item() for delta in DETERMINISTIC_STEPS]
    return {"exploratory_return": returns.mean().item(), **central_difference(plus, minus, STEP),
            "reinforce_raises": raises_fingers(reinforce).double().mean().item(),
            "enac_raises": raises_fingers(enac).double().mean().item(), "deterministic": deterministic}


def probe_job(job: FinishedRun) -> dict:
    """:func:`probe_controller` for every run of ``job``."""
    summary = job.summary
    if summary["env"] != "ballcatch" or summary["actor"] != "linear" or summary["explorer"] != "sde":
        raise SystemExit(f"error: {job.path} is not a linear ball-catching job with SDE")
    env_config = summary["config"]["env"]
    if env_config["observation"] != "raw":
        raise SystemExit(f"error: {job.path}: the probe reads controllers of the raw ball position")
    params = summary["final_parameters"]
    weight = next(torch.tensor(v, dtype=torch.float64) for k, v in params.items() if k.endswith("module.weight"))
    sigma_params = [torch.tensor(v, dtype=torch.float64) for k, v in params.items() if k.endswith("sigma_param")]
    if len(sigma_params) != 1:
        raise SystemExit(f"error: {job.path}: the probe needs the learned σ̂ in final_parameters")
    transform = summary["config"]["explorer"]["sigma_transform"]
    sigma = sigma_from_param(sigma_params[0], transform).reshape(-1, 4, 3).expand(weight.shape[0], 4, 3)
    config = BallCatchConfig(jitter=env_config["jitter"], model=env_config["model"])
    steps = env_config["episode_length"]
    explore = BatchedBallCatchEnv(num_worlds=EPISODES, config=config, max_steps=steps)
    evaluate = BatchedBallCatchEnv(num_worlds=DETERMINISTIC_BALLS, config=config, max_steps=steps)
    factor, first = mean_reward_factor(summary), summary["first_run"]
    runs = []
    try:
        for index, final in enumerate(summary["final_eval_return"]):
            run = first + index
            numbers = probe_controller(weight[index].reshape(4, 3), sigma[index], SEED_BASE + run, explore, evaluate,
                                       steps)
            runs.append({"run": run, "final": factor * final, **numbers})
            log.info("%s: run %d: closing %+.3f [%+.3f, %+.3f], REINFORCE %.1f, ENAC %.1f", job.path, run,
                     numbers["derivative"], numbers["low"], numbers["high"], numbers["reinforce_raises"],
                     numbers["enac_raises"])
    finally:
        explore.close()
        evaluate.close()
    return {"rest": REST, "release": RELEASE, "episodes": EPISODES, "batch": BATCH, "step": STEP,
            "seed_base": SEED_BASE, "deterministic_steps": DETERMINISTIC_STEPS,
            "deterministic_balls": DETERMINISTIC_BALLS, "runs": runs}


def level_numbers(runs: list[dict]) -> dict:
    """Per level group: runs, how closing does, the estimators' mean shares and the deterministic
    levels after each closing step."""
    numbers = {"runs": len(runs), **{c: sum(closing_pays(r) == c for r in runs) for c in ("pays", "flat", "costs")},
               "median_derivative": statistics.median(r["derivative"] for r in runs)}
    paying = [r for r in runs if closing_pays(r) == "pays"]
    for name in ("reinforce", "enac"):
        numbers[f"{name}_all"] = statistics.fmean(r[f"{name}_raises"] for r in runs)
        numbers[f"{name}_paying"] = statistics.fmean(r[f"{name}_raises"] for r in paying) if paying else None
    numbers["deterministic"] = [
        {"step": delta, "mean": statistics.fmean(r["deterministic"][i] for r in runs),
         "catch": sum(r["deterministic"][i] >= -1.1 for r in runs),
         "good": sum(r["deterministic"][i] >= -1.0 for r in runs)}
        for i, delta in enumerate(DETERMINISTIC_STEPS)]
    return numbers


def verdict(catch_level_runs: dict) -> str:
    """The rule's verdict from the catch-level group's numbers.

    Examples:
        >>> verdict({"runs": 8, "pays": 2, "reinforce_paying": 0.5, "enac_paying": 0.9})
        'premise refuted'
        >>> verdict({"runs": 8, "pays": 6, "reinforce_paying": 0.5, "enac_paying": 0.8})
        'confirmed'
        >>> verdict({"runs": 8, "pays": 6, "reinforce_paying": 0.75, "enac_paying": 0.8})
        'refuted'
        >>> verdict({"runs": 8, "pays": 6, "reinforce_paying": 0.65, "enac_paying": 0.8})
        'open'
    """
    if catch_level_runs["pays"] <= catch_level_runs["runs"] / 4:
        return "premise refuted"
    r, e = catch_level_runs["reinforce_paying"], catch_level_runs["enac_paying"]
    if e >= 0.7 and r <= 0.6:
        return "confirmed"
    return "refuted" if r >= 0.7 else "open"


VERDICTS = {
    "premise refuted": "closing pays for a quarter of these controllers or fewer: their exploratory return does "
                       "not reward closing the hand, so the shortfall is not the estimator's",
    "confirmed": "REINFORCE's 20-episode estimate misses a closing direction that pays, where ENAC's finds it",
    "refuted": "REINFORCE's estimate raises the fingers where closing pays: the shortfall is in how far its steps "
               "carry, not in where they point",
    "open": "neither threshold of the rule is met",
}


def markdown(numbers: dict) -> str:
    catch = numbers["levels"]["catch"]
    share = "n/a" if catch["reinforce_paying"] is None else f"{catch['reinforce_paying']:.2f}"
    enac = "n/a" if catch["enac_paying"] is None else f"{catch['enac_paying']:.2f}"
    lines = [
        "# Ball catching: does closing the hand pay under exploration, and which estimator sees it",
        "",
        f"**{numbers['verdict'].capitalize()}**: {VERDICTS[numbers['verdict']]}. Over the {catch['runs']} final "
        f"controllers of REINFORCE + SDE that end with a catch but not a good one, closing the hand raises the "
        f"exploratory return for {catch['pays']}; where it does, a batch of 20 episodes gives a REINFORCE estimate "
        f"that raises the fingers in a share {share} of batches, an ENAC estimate in {enac}.",
        "",
        f"Written by `analysis/paper/ballcatch_finger_probe.py` (rule: `finger_probe_rule.md`) from "
        f"`{numbers['sweep']}`. Per controller: {EPISODES} exploratory episodes at its own final σ̂ in the "
        f"shipped arm; **closing**: the derivative of their mean return along the step that raises the finger "
        f"command's pre-activation at a ball resting against the fingers {REST} and leaves it at the release "
        f"{RELEASE} (central differences, "
        f"h = {STEP}, the same draws and balls on both sides), *pays* / *flat* / *costs* by its 95 % interval; "
        f"**REINFORCE** and **ENAC**: the mean share of the {EPISODES // BATCH} batches of {BATCH} episodes whose "
        "estimate (the shipped learner's variance-weighted scores, the mean reward per step as return) raises "
        "that pre-activation, over all runs of the level / over those where closing pays.",
        "",
        "| final level | runs | closing pays / flat / costs | median derivative | REINFORCE raises the fingers "
        "| ENAC raises the fingers |",
        "| --- | --- | --- | --- | --- | --- |",
    ]

    def shares(n: dict, name: str) -> str:
        paying = "-" if n[f"{name}_paying"] is None else f"{n[f'{name}_paying']:.2f}"
        return f"{n[f'{name}_all']:.2f} / {paying}"

    for level, n in numbers["levels"].items():
        lines.append(f"| {level} | {n['runs']} | {n['pays']} / {n['flat']} / {n['costs']} | "
                     f"{n['median_derivative']:+.3f} | {shares(n, 'reinforce')} | {shares(n, 'enac')} |")
    lines += [
        "",
        f"What the closing step would give without exploration: the deterministic return after a step δ "
        f"along it, on {DETERMINISTIC_BALLS} balls; mean, and runs reaching a catch / a good catch.",
        "",
        "| final level | runs | " + " | ".join(f"δ = {d:g}" for d in DETERMINISTIC_STEPS) + " |",
        "| --- | --- | " + " | ".join("---" for _ in DETERMINISTIC_STEPS) + " |",
    ]
    for level, n in numbers["levels"].items():
        cells = [f"{d['mean']:.3f}, {d['catch']} / {d['good']}" for d in n["deterministic"]]
        lines.append(f"| {level} | {n['runs']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__.splitlines()[0])
    parser.add_argument("sweep", type=Path, help="a linear SDE ball-catching sweep (its job directories)")
    parser.add_argument("--out", type=Path, required=True, help="where finger_probe.md and .json go")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    jobs = finished_jobs(args.sweep)
    if not jobs:
        parser.error(f"no finished jobs under {args.sweep}")
    runs = []
    for job in jobs:
        path = job.path / "finger_probe.json"
        if not path.is_file():
            path.write_text(json.dumps(probe_job(job), indent=1) + "\n")
        runs += json.loads(path.read_text())["runs"]
    grouped = {level: [r for r in runs if catch_level(r["final"]) == level] for level in LEVEL_NAMES}
    if not grouped["catch"]:
        parser.error("no run of the sweep ends at the catch level: the rule's verdict is taken over those")
    sweep = args.sweep.resolve()
    numbers = {"sweep": str(sweep.relative_to(REPO)) if sweep.is_relative_to(REPO) else str(args.sweep),
               "levels": {level: level_numbers(group) for level, group in grouped.items() if group}}
    numbers["verdict"] = verdict(numbers["levels"]["catch"])
    args.out.mkdir(parents=True, exist_ok=True)
    write_page_json(args.out / "finger_probe.json", numbers)
    (args.out / "finger_probe.md").write_text(markdown(numbers))
    catch = numbers["levels"]["catch"]
    shares = [catch[f"{name}_paying"] or 0.0 for name in ("reinforce", "enac")]
    print(f"closing the hand pays for {catch['pays']} of the {catch['runs']} controllers that end with a catch but "
          f"not a good one; where it does, REINFORCE's 20-episode estimate points that way in {shares[0]:.0%} of "
          f"batches, ENAC's in {shares[1]:.0%}. Verdict: {numbers['verdict']}, {VERDICTS[numbers['verdict']]}. "
          f"Wrote {args.out / 'finger_probe.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
