"""The learner selection for ball catching: each method's learner chosen by the rule in
``docs/study/ballcatch/learner_selection.md``: the same candidates for every method (8 in round 1, a
ninth in round 2), one job of 8 runs each on the tuning seed, the candidate with the most final
catches chosen per method and round.

``run`` trains the (method, candidate) jobs through ``train.py``, a few at a time
(``analysis/runner.py``), into ``OUT/<method>/<candidate>``, and keeps no checkpoint of a finished
one (a rerun skips the finished jobs and resumes the others); ``report`` reads them and
writes ``tuning.md`` and ``tuning.json``: per method and candidate the final catches, good
catches and mean final evaluation (the paper's mean reward per step), and the chosen candidate.

Usage:
    python -m analysis.selection.ballcatch_tuning run --out results/ballcatch/tuning [--methods reinforce_sde ...]
    python -m analysis.selection.ballcatch_tuning report --out docs/study/ballcatch results/ballcatch/tuning
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from analysis.figures import write_page_json
from analysis.runner import TrainJob, run_train_jobs

SEED, RUNS = 1000, 8
CATCH, GOOD_CATCH = -1.1, -1.0

#: method → (label, the command's overrides, α₀, whether the command learns σ̂): the rule's table
#: "The methods", in its order.
METHODS = {
    "reinforce_sde": ("REINFORCE + SDE", ["+experiment=ballcatch_paper"], 1e-4, True),
    "reinforce_rex": ("REINFORCE + REX", ["+experiment=ballcatch_paper", "explorer=rex"], 1e-4, True),
    "enac_sde": ("ENAC + SDE", ["+experiment=ballcatch_enac_paper"], 0.01, False),
    "enac_rex": ("ENAC + REX", ["+experiment=ballcatch_enac_paper", "explorer=rex"], 0.01, False),
    "gpomdp_sde": ("GPOMDP + SDE", ["+experiment=ballcatch_paper", "estimator=gpomdp"], 1e-4, True),
    "pgpe": ("PGPE", ["+experiment=ballcatch_paper", "explorer=pgpe", "estimator=pgpe", "explorer.symmetric=false"],
             1e-4, True),
}
_DECAY = ["optimizer.lr_schedule=linear", "optimizer.final_lr_fraction=0"]
#: candidate → (description, overrides given α₀): the rule's table "The grid" (C1–C8, round 1)
#: and its round 2 (C9).
CANDIDATES = {
    "C1": ("sum, sgd, α₀, constant", lambda a: ["estimator.episode_return=sum", "optimizer=sgd", f"lr={a:g}"]),
    "C2": ("mean, sgd, α₀, constant", lambda a: ["estimator.episode_return=mean", "optimizer=sgd", f"lr={a:g}"]),
    "C3": ("mean, sgd, α₀, linear decay", lambda a: ["estimator.episode_return=mean", "optimizer=sgd", f"lr={a:g}",
                                                    *_DECAY]),
    "C4": ("mean, sgd, 10 α₀, linear decay", lambda a: ["estimator.episode_return=mean", "optimizer=sgd",
                                                       f"lr={10 * a:g}", *_DECAY]),
    "C5": ("mean, momentum 0.9, α₀, linear decay", lambda a: ["estimator.episode_return=mean", "optimizer=momentum",
                                                             f"lr={a:g}", *_DECAY]),
    "C6": ("mean, adam, 1e-3, linear decay", lambda a: ["estimator.episode_return=mean", "optimizer=adam", "lr=0.001",
                                                       *_DECAY]),
    "C7": ("mean, adam, 3e-3, linear decay", lambda a: ["estimator.episode_return=mean", "optimizer=adam", "lr=0.003",
                                                       *_DECAY]),
    "C8": ("mean, adam, 1e-2, linear decay", lambda a: ["estimator.episode_return=mean", "optimizer=adam", "lr=0.01",
                                                       *_DECAY]),
    "C9": ("C7, σ̂ learning switched", lambda a: CANDIDATES["C7"][1](a)),
    "C10": ("C7, σ̂₀ = e⁻³", lambda a: [*CANDIDATES["C7"][1](a), "explorer.init_param=-3"]),
    "C11": ("C7, σ̂₀ = e⁻⁴", lambda a: [*CANDIDATES["C7"][1](a), "explorer.init_param=-4"]),
    "C12": ("C7, scaled observation and a constant feature", lambda a: [*CANDIDATES["C7"][1](a),
                                                                       "env.observation=scaled"]),
    "C13": ("C10, σ̂ fixed at e⁻³", lambda a: [*CANDIDATES["C10"][1](a), "explorer.learn_sigma=false"]),
    "C14": ("C10, σ̂'s parameters at 10 α", lambda a: [*CANDIDATES["C10"][1](a), "optimizer.sigma_lr_factor=10"]),
    "C15": ("C10, queued episodes scored as collected", lambda a: [*CANDIDATES["C10"][1](a),
                                                                  "queue_scores=as_collected"]),
    "C16": ("C1, queued episodes scored as collected", lambda a: [*CANDIDATES["C1"][1](a),
                                                                 "queue_scores=as_collected"]),
    "C17": ("C10 at α = 1e-2", lambda a: [*CANDIDATES["C10"][1](a), "lr=0.01"]),
    "C18": ("C10, α kept constant", lambda a: [*CANDIDATES["C10"][1](a), "optimizer.lr_schedule=constant"]),
}
#: the candidates that switch whether σ̂ is learned (fixed where the method's command learns it).
SIGMA_SWITCHED = ("C9",)
#: the candidates each round from round 4 on adds to the round before it (learner_selection.md;
#: round 4 added on 2026-12-04, round 5 on 2026-12-05, rounds 6 and 7 on 2026-12-06, round 8 on
#: 2026-12-07).
ADDED = {4: ("C13",), 5: ("C14",), 6: ("C15", "C16"), 7: ("C17",), 8: ("C18",)}


def _rounds() -> dict[int, list[str]]:
    """The candidates each round chooses among, in the order that breaks its last tie: rounds 1
    and 2 (C1–C8, then C9) and round 3 (added on 2026-12-03), then round 3's grid with every later
    round's additions (:data:`ADDED`)."""
    rounds = {1: list(CANDIDATES)[:8], 2: list(CANDIDATES)[:9], 3: ["C7", "C1", "C10", "C11", "C12"]}
    for round_, added in ADDED.items():
        rounds[round_] = [*rounds[round_ - 1], *added]
    return rounds


ROUNDS = _rounds()
#: round → (tuning seed, runs per job, folder under the tuning directory); rounds 4 on add their
#: candidates to round 3's jobs on the same seed.
ROUND_JOBS = {1: (SEED, RUNS, ""), 2: (SEED, RUNS, ""), **{r: (3000, 16, "round3") for r in ROUNDS if r >= 3}}
#: candidates that are another candidate's job for the methods whose command fixes σ̂ (ENAC):
#: C13 fixes σ̂ at e⁻³, which C10 already does there, and C14 steps a σ̂ that is not learned.
SAME_WHERE_SIGMA_FIXED = {"C13": "C10", "C14": "C10"}
#: rounds 3 on: the key of a method's choice in each round's numbers, and its mark in the table.
LATER_ROUNDS = {r: ("chosen" if r == 3 else f"chosen_round{r}", mark)
                for r, mark in zip(range(3, max(ROUNDS) + 1), "‡§¶◊※⁂", strict=True)}


def job_overrides(method: str, candidate: str, round_: int = 1) -> list[str]:
    """The ``train.py`` overrides of one tuning job of round ``round_`` (its seed and runs).

    Examples:
        >>> job_overrides("enac_rex", "C4")[:4]
        ['+experiment=ballcatch_enac_paper', 'explorer=rex', 'estimator.episode_return=mean', 'optimizer=sgd']
        >>> job_overrides("enac_rex", "C4")[4]
        'lr=0.1'
        >>> [o for o in job_overrides("enac_rex", "C9") if "sigma" in o]  # ENAC's command fixes σ̂
        ['explorer.learn_sigma=true']
        >>> job_overrides("reinforce_sde", "C10", round_=3)[-7:-3]
        ['explorer.init_param=-3', 'seed=3000', 'runs=16', 'first_run=0']
    """
    _, base, alpha, learns_sigma = METHODS[method]
    seed, runs, _ = ROUND_JOBS[round_]
    switch = [f"explorer.learn_sigma={str(not learns_sigma).lower()}"] if candidate in SIGMA_SWITCHED else []
    return [*base, *CANDIDATES[candidate][1](alpha), *switch, f"seed={seed}", f"runs={runs}", "first_run=0",
            "eval_period=50", "checkpoint_period=50", "logger=none"]


def jobs(out: Path, methods: list[str], candidates: list[str], round_: int = 1) -> list[TrainJob]:
    """The (method, candidate) jobs of round ``round_``, each in ``out/[round3/]<method>/<candidate>``.

    Examples:
        >>> [job.name for job in jobs(Path("tuning"), ["enac_sde"], ["C1", "C2"])]
        ['enac_sde/C1', 'enac_sde/C2']
        >>> [str(job.run_dir) for job in jobs(Path("tuning"), ["pgpe"], ["C7"], round_=3)]
        ['tuning/round3/pgpe/C7']
        >>> [job.name for job in jobs(Path("tuning"), ["enac_sde", "pgpe"], ["C13"], round_=4)]
        ['pgpe/C13']
        >>> jobs(Path("tuning"), ["pgpe"], ["C14"], round_=5)[0].overrides[-8:-6]
        ('explorer.init_param=-3', 'optimizer.sigma_lr_factor=10')
    """
    folder = out / ROUND_JOBS[round_][2]
    return [TrainJob(f"{m}/{c}", tuple(job_overrides(m, c, round_)), folder / m / c)
            for m in methods for c in candidates if job_candidate(m, c) == c]


def job_candidate(method: str, candidate: str) -> str:
    """The candidate whose job stands for ``candidate`` in ``method``: itself, or for a method
    whose command fixes σ̂ the candidate it equals there (``SAME_WHERE_SIGMA_FIXED``).

    Examples:
        >>> job_candidate("enac_sde", "C13"), job_candidate("reinforce_sde", "C13")
        ('C10', 'C13')
        >>> job_candidate("enac_rex", "C14"), job_candidate("pgpe", "C14")
        ('C10', 'C14')
    """
    learns_sigma = METHODS[method][3]
    return candidate if learns_sigma else SAME_WHERE_SIGMA_FIXED.get(candidate, candidate)


def final_evaluations(run_dir: Path) -> list[float] | None:
    """The runs' final deterministic evaluations in mean reward per step, or ``None`` for a job
    without a summary (failed or not run)."""
    from sde_torchrl.jobs.run_dir import read_finished_run
    from sde_torchrl.trainers.summary import mean_reward_factor

    if not (run_dir / "summary.json").exists():
        return None
    summary = read_finished_run(run_dir).summary
    return [mean_reward_factor(summary) * value for value in summary["final_eval_return"]]


def select(results: dict[str, list[float] | None], good_catches: bool = False) -> str | None:
    """The chosen candidate: most final catches, then (``good_catches``, round 3) the most final
    good catches, then the higher mean final evaluation, then the earlier candidate; a failed job
    counts as no catch (``None`` if no job has a summary).

    Examples:
        >>> select({"C1": [-1.0, -2.0], "C2": [-1.2, -1.5], "C3": None})
        'C1'
        >>> select({"C1": [-1.2, -2.0], "C2": [-1.5, -1.6]})
        'C2'
        >>> select({"C7": [-1.05, -1.3], "C10": [-0.99, -1.9]}, good_catches=True)
        'C10'
    """
    def key(item: tuple[int, tuple[str, list[float] | None]]) -> tuple:
        index, (_, finals) = item
        if finals is None:
            return (-1, -1, float("-inf"), -index)
        good = sum(value >= GOOD_CATCH for value in finals) if good_catches else 0
        return (sum(value >= CATCH for value in finals), good, sum(finals) / len(finals), -index)

    ran = [(i, item) for i, item in enumerate(results.items()) if item[1] is not None]
    return max(ran, key=key)[1][0] if ran else None


def report(tuning: Path, out: Path) -> dict:
    """Writes ``tuning.json`` and ``tuning.md`` into ``out``; returns the numbers. Each round
    gives a method its chosen candidate (``chosen`` for round 1, ``chosen_round2``) only once
    every candidate of that round has run (a directory that holds no summary is a failed job,
    counted as no catch; a missing one has not run)."""
    numbers: dict = {"seed": SEED, "runs": RUNS, "methods": {}}
    for method, (label, _, alpha, _) in METHODS.items():
        results = {c: final_evaluations(tuning / method / c) for c in ROUNDS[2]}
        if all(r is None for r in results.values()):
            continue

        chosen = [select({c: results[c] for c in ROUNDS[r]})  # a job that ran and failed counts
                  if all((tuning / method / c).is_dir() for c in ROUNDS[r]) else None for r in (1, 2)]
        numbers["methods"][method] = {
            "label": label, "alpha0": alpha, "chosen": chosen[0], "chosen_round2": chosen[1],
            "candidates": {c: candidate_numbers(r) for c, r in results.items()},
        }
    numbers["round3"] = round3_numbers(tuning / ROUND_JOBS[3][2])
    out.mkdir(parents=True, exist_ok=True)
    write_page_json(out / "tuning.json", numbers)
    (out / "tuning.md").write_text(markdown(numbers))
    return numbers


def candidate_numbers(finals: list[float] | None) -> dict | None:
    """A job's final catches, good catches and mean final evaluation (``None``: not run or failed)."""
    if finals is None:
        return None
    return {"catches": sum(v >= CATCH for v in finals), "good_catches": sum(v >= GOOD_CATCH for v in finals),
            "mean_final": sum(finals) / len(finals), "finals": finals}


def round3_numbers(folder: Path) -> dict:
    """The jobs of rounds 3 on under ``folder`` (``<method>/<candidate>``, one seed) and each method's
    choice in each round, made once all its candidates of that round have finished or failed
    (more catches, then good catches, then the mean; a failed job counts as no catch)."""
    seed, runs, _ = ROUND_JOBS[3]
    last = max(LATER_ROUNDS)
    methods = {}
    for method, (label, *_) in METHODS.items():
        results = {c: final_evaluations(folder / method / job_candidate(method, c)) for c in ROUNDS[last]}
        if all(r is None for r in results.values()):
            continue

        failed = [c for c, r in results.items()
                  if r is None and (folder / method / job_candidate(method, c) / "error.txt").exists()]
        methods[method] = {"label": label,
                           **{key: round_choice(folder, method, results, r) for r, (key, _) in LATER_ROUNDS.items()},
                           "same_as": {c: job_candidate(method, c) for c in ROUNDS[last]
                                       if job_candidate(method, c) != c},
                           "candidates": {c: candidate_numbers(r) for c, r in results.items()}, "failed": failed}
    return {"seed": seed, "runs": runs, "methods": methods}


def round_choice(folder: Path, method: str, results: dict[str, list[float] | None], round_: int) -> str | None:
    """``method``'s choice in round ``round_`` among ``results``, or ``None`` while one of the
    round's jobs under ``folder`` has neither finished nor failed (a running job has neither file)."""
    complete = all(any((folder / method / job_candidate(method, c) / name).exists()
                       for name in ("summary.json", "error.txt")) for c in ROUNDS[round_])
    return select({c: results[c] for c in ROUNDS[round_]}, good_catches=True) if complete else None


def round3_markdown(numbers: dict) -> list[str]:
    """The table of rounds 3 on: one row per candidate, one column per method that ran any of its jobs."""
    methods = numbers["methods"]
    if not methods:
        return []
    later = "".join(f", {LATER_ROUNDS[r][1]}: its choice in round {r} (the same with {' and '.join(added)})"
                    for r, added in ADDED.items())
    lines = ["", f"## Rounds 3 to {max(ROUNDS)} (seed {numbers['seed']}, {numbers['runs']} runs per job)", "",
             f"The same cells; {LATER_ROUNDS[3][1]}: the method's choice in round 3 ({', '.join(ROUNDS[3])}: most "
             f"final catches, then good catches, then the mean){later}, each made once all of "
             "that round's candidates have run; = C10: the same job "
             "(the method fixes σ̂ already); failed: the job stopped with an error (its `error.txt`), its runs "
             "counted as not catching.", "",
             "| candidate | " + " | ".join(m["label"] for m in methods.values()) + " |",
             "| --- |" + " --- |" * len(methods)]
    for candidate in ROUNDS[max(LATER_ROUNDS)]:
        cells = []
        for m in methods.values():
            c = m["candidates"][candidate]
            cell = "-" if c is None else f"{c['catches']} / {c['good_catches']}, {c['mean_final']:.2f}"
            if candidate in m.get("failed", []):
                cell = "failed"
            if candidate in m.get("same_as", {}):
                cell = f"= {m['same_as'][candidate]}"
            marks = [mark for key, mark in LATER_ROUNDS.values() if m.get(key) == candidate]
            cells.append(" ".join([cell, *marks]))
        lines.append(f"| {candidate}: {CANDIDATES[candidate][0]} | " + " | ".join(cells) + " |")
    for round_, (key, _) in LATER_ROUNDS.items():
        waiting = [m["label"] for m in methods.values() if m.get(key) is None]
        if waiting:
            lines += ["", f"Not chosen yet in round {round_}, its candidates not all run: {', '.join(waiting)}."]
    for round_ in list(LATER_ROUNDS)[1:]:
        key, before = LATER_ROUNDS[round_][0], LATER_ROUNDS[round_ - 1][0]
        decided = [m for m in methods.values() if m.get(key) is not None and m.get(before) is not None]
        changed = [f"{m['label']} {m[before]} → {m[key]}" for m in decided if m[key] != m[before]]
        if decided:
            lines += ["", f"Round {round_} changes the choice of: " + (", ".join(changed) if changed else "no method")
                      + f" (of the {len(decided)} methods it has decided)."]
    return lines


def markdown(numbers: dict) -> str:
    """The tables of ``tuning.md``: one row per candidate, one column per method."""
    methods = numbers["methods"]
    lines = [
        "# Ball catching: the learner selection",
        "",
        f"Written by `analysis/selection/ballcatch_tuning.py report` from the jobs under `results/ballcatch/tuning/` "
        f"(rule: `learner_selection.md`; seed {numbers['seed']}, {numbers['runs']} runs per job, 500 updates). "
        "A cell: runs whose final deterministic evaluation is a catch (R ≥ -1.1) / a good catch (R ≥ -1.0), "
        "and the mean final evaluation (mean reward per step); **bold**: the method's candidate chosen in "
        "round 1 (C1–C8, the shipped experiments and reported sweeps); †: its choice in round 2 (C1–C9); "
        "- : not run.",
        "",
        "| candidate | " + " | ".join(m["label"] for m in methods.values()) + " |",
        "| --- |" + " --- |" * len(methods),
    ]
    for candidate in ROUNDS[2]:
        description = CANDIDATES[candidate][0]
        cells = []
        for m in methods.values():
            c = m["candidates"][candidate]
            cell = "-" if c is None else f"{c['catches']} / {c['good_catches']}, {c['mean_final']:.2f}"
            cell = f"**{cell}**" if m["chosen"] == candidate else cell
            cells.append(f"{cell} †" if m["chosen_round2"] == candidate else cell)
        lines.append(f"| {candidate}: {description} | " + " | ".join(cells) + " |")
    for round_, key in ((1, "chosen"), (2, "chosen_round2")):
        waiting = [m["label"] for m in methods.values() if m[key] is None]
        if waiting:
            lines += ["", f"Not chosen yet in round {round_}, its candidates not all run: {', '.join(waiting)}."]
    changed = [f"{m['label']} {m['chosen']} → {m['chosen_round2']}" for m in methods.values()
               if m["chosen_round2"] is not None and m["chosen_round2"] != m["chosen"]]
    if all(m["chosen_round2"] is not None for m in methods.values()):
        lines += ["", "Round 2 changes the choice of: " + (", ".join(changed) if changed else "no method") + "."]
    lines += ["", "α₀: " + ", ".join(f"{m['label']} {m['alpha0']:g}" for m in methods.values()) + "."]
    lines += round3_markdown(numbers.get("round3", {"methods": {}}))
    return "\n".join([*lines, ""])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="train the tuning jobs")
    run.add_argument("--out", type=Path, required=True)
    run.add_argument("--methods", nargs="+", choices=list(METHODS), default=list(METHODS))
    run.add_argument("--candidates", nargs="+", choices=list(CANDIDATES), default=ROUNDS[1])
    run.add_argument("--workers", type=int, default=2)
    run.add_argument("--round", type=int, choices=list(ROUND_JOBS), default=1,
                     help="the round whose seed and runs the jobs take (round 3: seed 3000, 16 runs)")
    rep = sub.add_parser("report", help="write tuning.md / tuning.json")
    rep.add_argument("tuning", type=Path)
    rep.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    if args.command == "report":
        report(args.tuning, args.out)
        return 0
    if args.workers < 1:
        parser.error(f"--workers={args.workers}: a positive integer")
    if any(c not in ROUNDS[args.round] for c in args.candidates):
        parser.error(f"round {args.round}'s candidates are {' '.join(ROUNDS[args.round])}")
    failed = run_train_jobs(jobs(args.out, args.methods, args.candidates, args.round), args.workers, command=True,
                            keep_checkpoints=False)  # run outputs are committed, checkpoints are not
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
