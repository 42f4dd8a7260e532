"""Search for ONE learner setting, the same for REX and SDE, for Table 1 (paper section 4.1).

The task is the authors' (``conf/env/minimize.yaml``: x0 = 2, reward of the noise-free
successor, summed return, the paper's R_lim); what the paper leaves open is the learner. This
script tries the ingredients of the authors' PyBrain learner through the real pipeline (configs
composed from ``+experiment=noise_sweep`` / ``episode_length_sweep``, trainers with stacked runs
that stop once every run has exceeded R_lim) and writes what it tried, with the outcome in each
of the 8 Table-1 settings, to ``--out`` (``learner_search.md``, ``learner_search.json``).

Selection rule (written down, and committed, before any result of this search was seen):

1. A candidate learner is: scores (``variance_weighted``, the authors' "auto-alpha" scores, or
   ``plain`` likelihood gradients); step bound (``entry``: the authors' rescale of a gradient
   whose largest entry exceeds 1000, or ``norm``: a per-run norm bound of 100); episodes per
   update ``N`` ∈ {5, 10, 20, 50}; and α from a grid, largest first (variance-weighted scores:
   0.1 (the paper's α), 0.05, 0.02, 0.01, 0.005, 0.002; plain scores, whose directions are
   ``1/σ_j²`` longer (≈ 14× at x = 2, ≈ 200× at x = 0.5): 0.002, 0.001, 0.0005, 0.0002, 0.0001, 0.00005).
2. A candidate passes when, in every one of the 8 settings (σ_noise 0.5 / 1.0 / 1.5 at EL 15,
   R_lim = -1.6; EL 5 / 15 / 30 / 45 / 60 at σ_noise 0.5, R_lim = -1.8), every run of REX and
   of SDE stays finite and exceeds R_lim within 15,000 episodes. A run whose mean return falls
   below 100 times its first update's counts as diverged, as a non-finite one does (and ends
   its job at once). To keep the search near 20 min
   on 2 cores it uses 10 runs per job (seed 1), where Table 1 uses 30 (seed 0).
3. For each (scores, bound, N), α is the largest grid value that passes. α is tried from the
   largest down; a failure because some run did not reach R_lim within the budget ends the
   descent (a smaller α is slower still), a diverged run moves on to the next smaller α.
4. The chosen learner is the first (scores, bound) pair, in the order (variance-weighted,
   entry) [the authors' learner], (variance-weighted, norm), (plain, entry), (plain, norm), that
   has a passing N; within it, the N with the largest passing α; a tie in α goes to the N with
   the fewest episodes to R_lim summed over both methods and all 8 settings. Pairs after the
   first passing one cannot change the choice and are not run (``--all`` runs them anyway).

5. Added after the search had run and no candidate had passed (so the rule above chose nothing):
   the chosen learner is then the candidate tried with the fewest failed runs, a diverged job
   counting all its runs as failed and a job that missed R_lim its runs that missed: the pass
   criterion of step 2, counted instead of required.

Neither speed-ups nor the paper's episode counts enter the rule; the same learner serves both
methods, and no method is tuned alone.

Usage:
    python -m analysis.selection.learner_search --out docs/table1 [--workers 2] [--all]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from analysis.figures import write_page_json
from analysis.runner import JobPool

BUDGET = 15_000  # episodes per run
RUNS = 10
SEED = 1
PAIRS = (("variance_weighted", "entry"), ("variance_weighted", "norm"), ("plain", "entry"), ("plain", "norm"))
EPISODES_PER_UPDATE = (5, 10, 20, 50)
ALPHAS = {"variance_weighted": (0.1, 0.05, 0.02, 0.01, 0.005, 0.002),
          "plain": (0.002, 0.001, 0.0005, 0.0002, 0.0001, 0.00005)}
#: (experiment, override of the setting, label), the most fragile first (failures end a candidate early).
SETTINGS = (
    ("noise_sweep", "env.noise_std=1.5", "σ 1.5"), ("episode_length_sweep", "env.episode_length=60", "EL 60"),
    ("noise_sweep", "env.noise_std=1.0", "σ 1.0"), ("episode_length_sweep", "env.episode_length=45", "EL 45"),
    ("episode_length_sweep", "env.episode_length=30", "EL 30"), ("noise_sweep", "env.noise_std=0.5", "σ 0.5"),
    ("episode_length_sweep", "env.episode_length=15", "EL 15"),
    ("episode_length_sweep", "env.episode_length=5", "EL 5"),
)

log = logging.getLogger("learner_search")


@dataclass(frozen=True)
class Candidate:
    """One learner: scores, step bound, episodes per update and α."""

    scores: str
    bound: str
    episodes_per_update: int
    alpha: float

    def overrides(self) -> list[str]:
        """Config overrides that select this learner."""
        bound = (["estimator.max_grad_entry=1000", "estimator.max_grad_norm=null"] if self.bound == "entry"
                 else ["estimator.max_grad_entry=null", "estimator.max_grad_norm=100"])
        return [f"lr={self.alpha}", f"episodes_per_update={self.episodes_per_update}",
                f"updates={BUDGET // self.episodes_per_update}",
                f"estimator.variance_weighted={self.scores == 'variance_weighted'}", *bound]


def run_job(experiment: str, overrides: list[str]) -> dict:
    """Trains one job (in a worker process) by the trainer's own collect and update, until every
    run has exceeded R_lim, a run diverges, or the budget is spent; returns the outcome and each
    run's episodes to R_lim."""
    import torch

    from sde_torchrl.config.build import build_trainer
    from sde_torchrl.config.compose import compose
    from sde_torchrl.trainers.guard import NonFiniteError

    torch.set_num_threads(1)
    cfg = compose([f"+experiment={experiment}", *overrides])
    trainer = build_trainer(cfg)
    first: list[int | None] = [None] * cfg.runs
    initial = None
    try:
        for k in range(cfg.updates):
            returns = trainer.estimate(trainer.collect(), k)["return_mean"]
            initial = returns if initial is None else initial
            for r in (returns > cfg.r_lim).nonzero().flatten().tolist():
                first[r] = first[r] or trainer.episodes_after(k)
            if bool((returns < 100 * initial).any()):
                return {"outcome": "diverged", "detail": f"return below 100x the first at update {k}"}
            if all(e is not None for e in first):
                break
    except NonFiniteError as error:
        return {"outcome": "diverged", "detail": str(error).splitlines()[0]}
    finally:
        trainer.close()
    missed = sum(e is None for e in first)
    reached = [e for e in first if e is not None]
    return {"outcome": "reached" if not missed else "not reached", "missed": missed,
            "mean_episodes": statistics.mean(reached) if reached else None, "episodes": first}


def try_candidate(pool: JobPool, candidate: Candidate) -> dict:
    """Runs the 16 jobs of ``candidate`` (fragile settings first), stopping at its first failure
    (the jobs already started finish and are recorded)."""
    base = [f"runs={RUNS}", f"seed={SEED}", *candidate.overrides()]
    tasks = {(label, explorer): (experiment, [*base, setting, f"explorer={explorer}"])
             for experiment, setting, label in SETTINGS for explorer in ("rex", "sde")}
    found = pool.run(run_job, tasks, stop=lambda result: result["outcome"] != "reached")
    results: dict[str, dict[str, dict]] = {}
    for (label, explorer), result in found.items():
        results.setdefault(label, {})[explorer] = result
    failure = next((r["outcome"] for r in found.values() if r["outcome"] != "reached"), None)
    total = None if failure else sum(r["mean_episodes"] for per in results.values() for r in per.values())
    return {"candidate": asdict(candidate), "passed": failure is None, "failure": failure,
            "total_episodes": total, "settings": results}


def search(workers: int, run_all_pairs: bool, out: Path, resume: bool = False) -> dict:
    """Applies the selection rule of the module docstring; writes the table after every candidate.

    With ``resume``, candidates already in ``out/learner_search.json`` are not run again: their
    recorded results enter the rule as if just run (and if none is left to run, the recorded
    wall time is kept: the files are rewritten as they were).
    """
    tried, passing, chosen = [], {}, None
    done, recorded_wall_s = {}, None
    if resume and (out / "learner_search.json").exists():
        recorded = json.loads((out / "learner_search.json").read_text())
        done = {Candidate(**r["candidate"]): r for r in recorded["tried"]}
        recorded_wall_s = recorded.get("wall_s")
    offset = max((r["wall_s"] for r in done.values()), default=0.0)
    start = time.perf_counter() - offset
    ran = False
    with JobPool(workers) as pool:
        for scores, bound in PAIRS:
            if chosen is not None and not run_all_pairs:
                break
            for n in EPISODES_PER_UPDATE:
                for alpha in ALPHAS[scores]:
                    candidate = Candidate(scores, bound, n, alpha)
                    result = done.get(candidate)
                    if result is None:
                        result, ran = try_candidate(pool, candidate), True
                    result.setdefault("wall_s", round(time.perf_counter() - start, 1))
                    tried.append(result)
                    log.info("%s: %s", result["candidate"], "passed" if result["passed"] else result["failure"])
                    write_outputs(tried, passing, chosen, out)
                    if result["passed"]:
                        passing.setdefault((scores, bound), []).append(result)
                        break
                    if any(r["outcome"] == "not reached" for per in result["settings"].values()
                           for r in per.values()):
                        break  # some run too slow: a smaller α is slower still (rule, step 3)
            if chosen is None and passing.get((scores, bound)):
                chosen = min(passing[(scores, bound)],
                             key=lambda r: (-r["candidate"]["alpha"], r["total_episodes"]))["candidate"]
    if chosen is None:  # step 5
        chosen = min(tried, key=failed_runs)["candidate"]
    # nothing run in this session: the search's wall time is the one recorded
    wall_s = time.perf_counter() - start if ran or recorded_wall_s is None else recorded_wall_s
    write_outputs(tried, passing, chosen, out, wall_s=wall_s)
    return {"chosen": chosen, "tried": tried}


def failed_runs(result: dict) -> int:
    """Runs that failed the pass criterion in a candidate's jobs (a diverged job: all its runs)."""
    jobs = [r for per in result["settings"].values() for r in per.values()]
    return sum(RUNS if r["outcome"] == "diverged" else r.get("missed", 0) for r in jobs)


def _outcome(result: dict) -> str:
    """``pass``, or what failed: ``miss`` if a run missed R_lim (it ends the α descent), else ``diverged``."""
    if result["passed"]:
        return "pass"
    jobs = [r for per in result["settings"].values() for r in per.values()]
    kind = "miss" if any(r["outcome"] == "not reached" for r in jobs) else "diverged"
    return f"{kind} ({failed_runs(result)} failed runs)"


def _cell(per_setting: dict | None) -> str:
    """``REX / SDE`` mean episodes, or what went wrong, for one setting."""
    if not per_setting:
        return "·"
    parts = []
    for explorer in ("rex", "sde"):
        r = per_setting.get(explorer)
        if r is None:
            parts.append("·")
        elif r["outcome"] == "diverged":
            parts.append("div")
        elif r["outcome"] == "not reached":
            parts.append(f"{r['missed']}/{RUNS} miss")
        else:
            parts.append(f"{r['mean_episodes']:.0f}")
    return " / ".join(parts)


def write_outputs(tried: list[dict], passing: dict, chosen: dict | None, out: Path,
                  wall_s: float | None = None) -> None:
    """``learner_search.md`` (one row per candidate tried) and ``learner_search.json``."""
    labels = [label for _, _, label in SETTINGS]
    lines = [
        "Learner search (analysis/selection/learner_search.py; rule in its docstring): per setting, mean episodes "
        f"to R_lim of REX / SDE over {RUNS} runs (seed {SEED}), `div` = a run diverged (non-finite, or "
        "below 100× its first return), "
        f"`k/{RUNS} miss` = k runs did not reach R_lim within {BUDGET:,} episodes, `·` = not run "
        "(the candidate had already failed).",
        "",
        "| scores | bound | N | α | " + " | ".join(labels) + " | outcome |",
        "| --- | --- | --- | --- | " + " | ".join("---" for _ in labels) + " | --- |",
    ]
    for result in tried:
        c = result["candidate"]
        outcome = _outcome(result)
        if chosen == c:
            outcome = f"**chosen**: {outcome}"
        lines.append(f"| {c['scores']} | {c['bound']} | {c['episodes_per_update']} | {c['alpha']:g} | "
                     + " | ".join(_cell(result["settings"].get(label)) for label in labels) + f" | {outcome} |")
    if chosen:
        how = "by step 4" if passing else "by step 5: no candidate passed"
        lines += ["", f"Chosen ({how}): {chosen['scores']} scores, {chosen['bound']} bound, N = "
                      f"{chosen['episodes_per_update']}, α = {chosen['alpha']:g}."]
    if wall_s is not None:
        lines += ["", f"Search wall time: {wall_s:.0f} s."]
    out.mkdir(parents=True, exist_ok=True)
    (out / "learner_search.md").write_text("\n".join(lines) + "\n")
    # also the search's record, read back by --resume (a candidate's α and counts are exact at 6 digits)
    write_page_json(out / "learner_search.json", {
        "rule": __doc__.split("Selection rule")[1].split("Usage:")[0].strip(), "runs": RUNS, "seed": SEED,
        "budget_episodes": BUDGET, "chosen": chosen, "tried": tried, "wall_s": wall_s})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="where learner_search.md/json go")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--all", action="store_true", help="also search the pairs after the first passing one")
    parser.add_argument("--resume", action="store_true", help="reuse the candidates already in --out")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    result = search(args.workers, args.all, args.out, args.resume)
    print(json.dumps({"chosen": result["chosen"], "candidates_tried": len(result["tried"])}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
