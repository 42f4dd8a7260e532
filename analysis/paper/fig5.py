"""Ball catching, paper Fig. 5 (REINFORCE) and Fig. 6 (ENAC): learning curves and catch counts.

Reads one or more sweep directories (shards of the same sweep may be split over processes or
machines: runs are merged by their global index, a run found twice must agree), keeps the runs
of one estimator, and writes into ``--out DIR``:

- ``fig5.png`` (``fig6.png`` for ENAC): left, the deterministic evaluation returns over the
  updates (mean reward per step, the paper's units), mean over runs with its 95 % bootstrap
  band, SDE and REX; right, the percent of runs whose best evaluated policy reached
  R ≥ -2.0, -1.5, -1.1, -1.0, with 95 % Wilson intervals, and the paper's where it states them;
- ``fig5.json`` / ``fig5.md``: those counts per explorer, best and final, with their intervals,
  beside the paper's, and the SDE − REX differences with bootstrap intervals (significant
  where the interval excludes 0); with the ``initial.json`` files of
  ``analysis/paper/ballcatch_initial.py`` under the sweep directories, the mean initial and final
  evaluations and the mean change per run with its bootstrap interval; for runs whose
  ``metrics.csv`` records the exploration state (``sigma_min``, ``sigma_max``), how many runs'
  exploration collapsed (a scale below :data:`COLLAPSE`: some of it, or all of it) and when;
  and whether runs kept their level (:func:`kept`: the drop from the best mean of
  :data:`WINDOW` consecutive evaluations to the last such mean).

With ``--estimator all`` it compares the methods of the REINFORCE sweeps, beyond the paper's two: SDE and
REX with REINFORCE, SDE with GPOMDP (``sde+gpomdp``) and PGPE, written as ``methods.*``, with
every method's difference from REINFORCE + SDE (and PGPE's from REX) in the same form.

Sweeps it cannot make the figure from (a job not finished, copies of a run that disagree, final
policies of some runs only, no run of the estimator) are refused in one line on stderr,
``error: ...``, with exit code 2.

Usage:
    python -m analysis.paper.fig5 --out results/fig5 multirun/2026-11-22/10-00-00 [more shards...]
    python -m analysis.paper.fig5 --estimator enac --out results/fig6 SWEEP_DIR
    python -m analysis.paper.fig5 --estimator all --out results/methods FIG5_SWEEP GPOMDP_SWEEP PGPE_SWEEP
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from analysis.figures import bounds, difference_of_means, saved_figure, style, write_page_json
from analysis.sweeps import EXIT_REFUSED, finished_jobs

#: Levels of the paper's right-hand plots: "slowed down", "kept on the fingers", "catch",
#: "good catch".
LEVELS = (-2.0, -1.5, -1.1, -1.0)
#: The paper's catch: closing the hand and holding the ball (R ≥ -1.1).
CATCH = -1.1
#: The paper's counts out of 100 runs where it states them (section 4.2).
PAPER = {
    "reinforce": {"sde": {-1.0: 68, -1.1: 98}, "rex": {-1.0: 7}},
    "enac": {"sde": {-1.1: 93}, "rex": {-1.1: 67}},  # "SDE outperformed REX by over 38%"
}
PAPER["all"] = PAPER["reinforce"]
FIGURE = {"reinforce": "fig5", "enac": "fig6", "all": "methods"}
#: A run's exploration has collapsed where its scale (SDE's σ̂, PGPE's |σ|) fell below this: 1/135
#: of the start σ̂₀ = e⁻², a noise of about 0.005 on a torque at the ball's distance of 5 units.
COLLAPSE = 1e-3
#: Consecutive evaluations averaged when asking whether a run kept its level: 5 evaluations of 3
#: episodes each (100 updates at the paper's period of 20), so that one lucky evaluation is not a peak.
WINDOW = 5
#: ``--estimator all``: the estimators compared on the REINFORCE sweeps' settings.
COMPARED = ("reinforce", "gpomdp", "pgpe")
#: ``--estimator all``: (method, baseline) pairs whose differences are reported.
VERSUS = (("sde", "rex"), ("sde+gpomdp", "sde"), ("pgpe", "sde"), ("pgpe", "rex"))


class Refused(ValueError):
    """Sweeps the figure cannot be made from; :func:`main` reports it in one line, exit code 2."""


def method_label(explorer: str, estimator: str, wanted: str) -> str | None:
    """The run's label in the figure, or ``None`` if the figure leaves it out: the explorer for
    one estimator; with ``wanted="all"``, ``explorer`` for REINFORCE, ``explorer+estimator`` for
    GPOMDP, ``pgpe`` for PGPE.

    Examples:
        >>> method_label("sde", "gpomdp", "all"), method_label("sde", "gpomdp", "reinforce")
        ('sde+gpomdp', None)
    """
    if wanted != "all":
        return explorer if estimator == wanted else None
    if estimator not in COMPARED:
        return None
    return explorer if estimator in ("reinforce", explorer) else f"{explorer}+{estimator}"


def load_runs(directories: list[Path], estimator: str) -> dict[str, dict[int, dict]]:
    """``explorer → global run index → {"evals": [(update, return)], "final": R, "collapse": …}``,
    returns as mean rewards per step (the paper's levels) whatever the job's ``episode_return``;
    ``collapse`` is ``None`` for runs written before ``metrics.csv`` recorded the exploration
    state, else the first update (0-based, or ``None``) at which ``any`` / ``all`` of the run's
    exploration scales were below :data:`COLLAPSE`."""
    from sde_torchrl.trainers.summary import mean_reward_factor

    runs: dict[str, dict[int, dict]] = {}
    for job in finished_jobs(*directories):  # refuses a job not finished or not started, by name
        summary = job.summary
        explorer = method_label(summary["explorer"], summary.get("estimator"), estimator)
        if explorer is None:
            continue
        scale = mean_reward_factor(summary)
        evals = job.series("eval_return")
        smallest, largest = job.series("sigma_min"), job.series("sigma_max")
        for offset, final in enumerate(summary["final_eval_return"]):
            index = summary["first_run"] + offset
            collapse = None if index not in smallest else {  # recorded: the first update below COLLAPSE
                key: next((update for update, sigma in series[index] if sigma < COLLAPSE), None)
                for key, series in (("any", smallest), ("all", largest))}
            run = {"evals": [(update, scale * value) for update, value in evals[index]], "final": scale * final,
                   "collapse": collapse}
            previous = runs.setdefault(explorer, {}).setdefault(index, run)
            if previous != run:
                raise Refused(f"run {index} of {explorer} appears twice with different results "
                                 f"(second copy in {job.path})")
    return runs


def read_json(path: Path, *keys: str) -> dict:
    """The JSON object in ``path``, which must hold ``keys``.

    Raises:
        Refused: the file cannot be read, is not a JSON object, or lacks one of ``keys``.
    """
    try:
        found = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise Refused(f"{path} cannot be read as JSON ({' '.join(str(error).split())}): write it again") from None
    missing = [key for key in keys if not isinstance(found, dict) or key not in found]
    if missing:
        raise Refused(f"{path} has no {', '.join(missing)}: not the file this figure reads; write it again")
    return found


def load_per_run(directories: list[Path], estimator: str, filename: str, key: str) -> dict[str, dict[int, float]]:
    """``explorer → global run index → value`` from the files ``filename`` under ``directories``
    that list one value per run under ``key`` (mean reward per step): ``initial.json``
    (``initial_eval_return``, ``analysis/paper/ballcatch_initial.py``), ``final_policy.json``
    (``final_policy_return``, ``analysis/paper/ballcatch_final.py``)."""
    values: dict[str, dict[int, float]] = {}
    for directory in directories:
        for path in sorted(directory.rglob(filename)):
            found = read_json(path, "explorer", "estimator", "first_run", key)
            label = method_label(found["explorer"], found["estimator"], estimator)
            if label is not None:
                for offset, value in enumerate(found[key]):
                    values.setdefault(label, {})[found["first_run"] + offset] = value
    return values


def behaviour_counts(directories: list[Path], estimator: str) -> dict[str, dict[str, int]]:
    """``explorer → behaviour → episodes`` of the final policies re-evaluated in the job's own arm
    with their behaviour (``reevaluation_pybrain.json``, ``analysis/paper/ballcatch_final.py --model
    pybrain``), for the explorers whose every job has one."""
    from sde_torchrl.envs.ballcatch.outcomes import BEHAVIOURS

    counts: dict[str, dict[str, int]] = {}
    for directory in directories:
        for path in sorted(directory.rglob("reevaluation_pybrain.json")):
            found = read_json(path, "explorer", "estimator", "per_episode")
            label = method_label(found["explorer"], found["estimator"], estimator)
            if label is not None:
                codes = [code for run in found["per_episode"]["behaviour"] for code in run]
                total = counts.setdefault(label, dict.fromkeys(BEHAVIOURS, 0))
                for code, name in enumerate(BEHAVIOURS):
                    total[name] += codes.count(code)
    return counts


def final_policy_episodes(directories: list[Path]) -> tuple[int, int] | None:
    """The episodes and seed of the ``final_policy.json`` files under ``directories`` as
    ``(episodes, seed)``, or ``None`` if there are none; files that disagree are refused."""
    found = {(f["episodes"], f["seed"]) for directory in directories
             for f in (read_json(path, "episodes", "seed") for path in sorted(directory.rglob("final_policy.json")))}
    if len(found) > 1:
        raise Refused(f"final_policy.json files of different evaluations {sorted(found)}: use one")
    return found.pop() if found else None


def improvement(by_run: dict[int, dict], initial: dict[int, float]) -> dict | None:
    """Mean initial and final evaluation over the runs, and the mean per-run change final −
    initial with its 95 % bootstrap interval; ``None`` unless every run has an initial one."""
    from sde_torchrl.utils.intervals import bootstrap_interval

    if not by_run.keys() <= initial.keys():
        return None
    change = bootstrap_interval([by_run[i]["final"] - initial[i] for i in sorted(by_run)])
    return {"initial_mean": sum(initial[i] for i in by_run) / len(by_run),
            "final_mean": sum(run["final"] for run in by_run.values()) / len(by_run),
            "change": list(change)}


def reached(runs: dict[int, dict], final_policy: dict[int, float] | None = None) -> dict[str, dict[str, list[bool]]]:
    """Per run (in index order), whether its best and its final evaluated policy reached each
    level; with ``final_policy`` (run index → the final policy's return on more episodes), also
    whether that did (``"final_policy"``)."""
    ordered = sorted(runs)
    values = {"best": [max(r for _, r in runs[index]["evals"]) for index in ordered],
              "final": [runs[index]["final"] for index in ordered]}
    if final_policy is not None:
        values["final_policy"] = [final_policy[index] for index in ordered]
    return {kind: {f"{level}": [value >= level for value in found] for level in LEVELS}
            for kind, found in values.items()}


def collapsed(by_run: dict[int, dict]) -> dict | None:
    """Of the runs that record their exploration state: how many had some / all of their
    exploration scales fall below :data:`COLLAPSE`, and the first such update (median, range,
    1-based); ``None`` if no run records it."""
    recorded = [run["collapse"] for run in by_run.values() if run.get("collapse") is not None]
    if not recorded:
        return None
    out = {"level": COLLAPSE, "recorded": len(recorded)}
    for key in ("any", "all"):
        updates = sorted(first[key] + 1 for first in recorded if first[key] is not None)
        out[key] = {"runs": len(updates), "median_update": updates[len(updates) // 2] if updates else None,
                    "first_update": updates[0] if updates else None, "last_update": updates[-1] if updates else None}
    return out


def first_evaluation(by_run: dict[int, dict]) -> dict | None:
    """What the runs reached at their first evaluation during training, beside their final one:
    the update of that evaluation (1-based: after that many updates) and, per level, the runs
    whose evaluation reached it then. Read beside the final counts, it says what the rest of
    training added. ``None`` if a run has no evaluation during training or the runs' first ones
    come after different updates.

    Examples:
        >>> runs = {0: {"evals": [(19, -1.05), (39, -1.2)], "final": -1.2},
        ...         1: {"evals": [(19, -2.5), (39, -0.9)], "final": -0.9}}
        >>> first_evaluation(runs)
        {'update': 20, 'reached': {'-2.0': 1, '-1.5': 1, '-1.1': 1, '-1.0': 0}}
    """
    firsts = [min(run["evals"]) for run in by_run.values() if run["evals"]]
    if len(firsts) != len(by_run) or len({update for update, _ in firsts}) != 1:
        return None
    return {"update": firsts[0][0] + 1,
            "reached": {f"{level}": sum(value >= level for _, value in firsts) for level in LEVELS}}


def catch_held(by_run: dict[int, dict]) -> dict | None:
    """How steadily runs stay at a catch once they reach one: over the runs whose evaluations
    reach a catch (R ≥ -1.1) before their last, the mean share of the evaluations after their
    first catching one that are catches too (1: never below again), and the runs counted.
    ``None`` if no run reaches a catch before its last evaluation.

    Examples:
        >>> runs = {0: {"evals": [(19, -1.5), (39, -1.05), (59, -1.2), (79, -1.0)]},
        ...         1: {"evals": [(19, -1.0), (39, -0.9), (59, -0.95), (79, -1.0)]},
        ...         2: {"evals": [(19, -2.0), (39, -2.0), (59, -1.5), (79, -1.05)]}}
        >>> catch_held(runs)
        {'share': 0.75, 'runs': 2}
    """
    shares = []
    for run in by_run.values():
        values = [value for _, value in sorted(run["evals"])]
        first = next((i for i, value in enumerate(values[:-1]) if value >= CATCH), None)
        if first is not None:
            later = values[first + 1:]
            shares.append(sum(value >= CATCH for value in later) / len(later))
    return {"share": sum(shares) / len(shares), "runs": len(shares)} if shares else None


def kept(by_run: dict[int, dict], window: int = WINDOW) -> dict | None:
    """Whether runs keep their level: per run, the best mean of ``window`` consecutive
    evaluations minus the mean of the last ``window`` (the drop from its peak: 0 where the run
    ends at its best), as the median run's and the quartiles'; and the runs whose ``window``-mean
    reached a catch (R ≥ -1.1) at some point and at the end. ``None`` if no run has ``2 window``
    evaluations.

    Examples:
        >>> runs = {0: {"evals": [(u, -2.0) for u in range(5)] + [(u, -1.0) for u in range(5, 10)]},
        ...         1: {"evals": [(u, -1.0) for u in range(5)] + [(u, -2.0) for u in range(5, 10)]}}
        >>> k = kept(runs)
        >>> k["drop"], k["catch_some_window"], k["catch_last_window"]
        ([0.25, 0.5, 0.75], 2, 1)
    """
    import numpy as np

    curves = [[value for _, value in sorted(run["evals"])] for run in by_run.values()]
    curves = [np.asarray(curve) for curve in curves if len(curve) >= 2 * window]
    if not curves:
        return None
    means = [np.convolve(curve, np.ones(window) / window, mode="valid") for curve in curves]
    drops = [float(m.max() - m[-1]) for m in means]
    return {"window": window, "runs": len(curves), "drop": [float(q) for q in np.quantile(drops, [0.25, 0.5, 0.75])],
            "catch_some_window": sum(bool(m.max() >= CATCH) for m in means),
            "catch_last_window": sum(bool(m[-1] >= CATCH) for m in means)}


def report(runs: dict[str, dict[int, dict]], estimator: str,
           initial: dict[str, dict[int, float]] | None = None,
           final_policy: dict[str, dict[int, float]] | None = None) -> dict:
    """The figure's numbers: per explorer, run count, catch counts (best and final) with their
    95 % Wilson intervals as fractions of the runs, and the paper's counts (out of 100); with
    both explorers, the SDE − REX difference of each fraction with its 95 % bootstrap interval
    over runs (``significant``: the interval excludes 0). With ``final_policy`` (explorer → run
    index → the final policy's return on more episodes), the same for ``"final_policy"``.

    Raises:
        Refused: ``final_policy`` has some of an explorer's runs but not all.
    """
    from sde_torchrl.utils.intervals import binomial_interval, bootstrap_interval

    final_policy = final_policy or {}
    for explorer, values in final_policy.items():
        missing = sorted(runs.get(explorer, {}).keys() - values.keys())
        if missing:
            raise Refused(f"{explorer}: {len(missing)} runs (first {missing[0]}) have no final_policy.json "
                          "entry: run analysis/paper/ballcatch_final.py on every shard")
    flags = {explorer: reached(by_run, final_policy.get(explorer)) for explorer, by_run in runs.items()}
    explorers = {}
    for explorer, by_run in sorted(runs.items()):
        n, stats = len(by_run), {"runs": len(by_run)}
        for kind in flags[explorer]:
            stats[kind] = {level: sum(hits) for level, hits in flags[explorer][kind].items()}
            stats[f"{kind}_interval"] = {level: bounds(binomial_interval(k, n)) for level, k in stats[kind].items()}
        stats["paper"] = {f"{k}": v for k, v in PAPER[estimator].get(explorer, {}).items()}
        stats["improvement"] = improvement(by_run, (initial or {}).get(explorer, {}))
        stats["collapse"] = collapsed(by_run)
        stats["kept"] = kept(by_run)
        stats["first_evaluation"] = first_evaluation(by_run)
        stats["catch_held"] = catch_held(by_run)
        explorers[explorer] = stats
    result = {"estimator": estimator, "explorers": explorers}

    def difference(method: str, baseline: str) -> dict:
        out, shared = {}, [kind for kind in flags[method] if kind in flags[baseline]]
        for kind in shared:
            out[kind] = {}
            for level in flags[method][kind]:
                ours, theirs = flags[method][kind][level], flags[baseline][kind][level]
                estimate, low, high = bootstrap_interval((ours, theirs), difference_of_means)
                out[kind][level] = {"estimate": estimate, "interval": [low, high],
                                    "significant": not low <= 0.0 <= high}
        return out

    if {"sde", "rex"} <= runs.keys():
        result["sde_minus_rex"] = difference("sde", "rex")
    if estimator == "all":
        result["differences"] = {f"{a} − {b}": difference(a, b) for a, b in VERSUS if {a, b} <= runs.keys()}
    return result


def _percent(fraction: float) -> str:
    return f"{100 * fraction:.0f}"


def _fraction_cell(stats: dict, kind: str, level: str) -> str:
    """``percent % [low, high]``: the runs of one explorer whose ``kind`` evaluation reached ``level``."""
    low, high = stats[f"{kind}_interval"][level]
    return f"{_percent(stats[kind][level] / stats['runs'])} % [{_percent(low)}, {_percent(high)}]"


def _difference_cell(difference: dict) -> str:
    """``+points [low, high]`` with ``*`` where the interval excludes 0."""
    low, high = difference["interval"]
    return (f"{100 * difference['estimate']:+.0f} [{100 * low:+.0f}, {100 * high:+.0f}]"
            + ("*" if difference["significant"] else ""))


def _table(result: dict, differences: dict[str, dict], kinds: tuple[str, ...], paper: bool) -> list[str]:
    """One row per explorer that has every kind in ``kinds`` (cells ``kind / kind`` per level, the
    paper's count with ``paper``), then the differences' rows."""
    lines = ["| explorer | runs | " + " | ".join(f"R ≥ {level}" for level in LEVELS) + " |",
             "| --- | --- | " + " | ".join("---" for _ in LEVELS) + " |"]
    for explorer, stats in result["explorers"].items():
        if all(kind in stats for kind in kinds):
            cells = [" / ".join(_fraction_cell(stats, kind, level) for kind in kinds)
                     + (f" (paper {stats['paper'][level]} %)" if paper and level in stats["paper"] else "")
                     for level in (f"{level}" for level in LEVELS)]
            lines.append(f"| {explorer.upper()} | {stats['runs']} | " + " | ".join(cells) + " |")
    for name, versus in differences.items():
        if all(kind in versus for kind in kinds):
            cells = [" / ".join(_difference_cell(versus[kind][f"{level}"]) for kind in kinds) for level in LEVELS]
            lines.append(f"| {name.upper()} (points) |  | " + " | ".join(cells) + " |")
    return lines


def write_markdown(result: dict, path: Path) -> None:
    """Per level, the fraction of runs (best / final evaluated policy) with its 95 % interval,
    beside the paper's; then the SDE − REX differences; then, if measured, the same for the
    final policies evaluated on more episodes (``analysis/paper/ballcatch_final.py``)."""
    differences = result.get("differences") or (
        {"sde − rex": result["sde_minus_rex"]} if "sde_minus_rex" in result else {})
    lines = _table(result, differences, ("best", "final"), paper=True)
    if "final_policy" in result:
        episodes, seed = result["final_policy"]["episodes"], result["final_policy"]["seed"]
        lines += ["", f"The final policy evaluated on {episodes} episodes (seed {seed}; "
                  "`analysis/paper/ballcatch_final.py`, rule in `docs/study/ballcatch/final_policy_rule.md`), "
                  "percent of runs whose mean reward over them reached the level:", ""]
        lines += _table(result, differences, ("final_policy",), paper=False)
    for explorer, counts in result.get("behaviours", {}).items():
        episodes = sum(counts.values())
        lines += ["", f"{explorer.upper()}: what the final policies do on those episodes ({episodes}): "
                  + ", ".join(f"{name} {_percent(count / episodes)} %" for name, count in counts.items())
                  + " (dropped: the ball touched the ground; held: not dropped, the hand closing at the last step; "
                  "kept on the hand: not dropped, the hand not closing)"]
    for explorer, stats in result["explorers"].items():
        if stats["improvement"]:
            change = stats["improvement"]["change"]
            lines += ["", f"{explorer.upper()}: mean evaluation {stats['improvement']['initial_mean']:.3f} (Θ0) → "
                      f"{stats['improvement']['final_mean']:.3f} (final); mean change per run {change[0]:+.3f} "
                      f"[{change[1]:+.3f}, {change[2]:+.3f}]"]
    for explorer, stats in result["explorers"].items():
        if stats.get("collapse"):
            c = stats["collapse"]
            parts = [f"{c[key]['runs']} of {c['recorded']} runs with {words} below {c['level']:g}"
                     + (f" (from update {c[key]['median_update']} in the median run, {c[key]['first_update']}"
                        f"-{c[key]['last_update']})" if c[key]["runs"] else "")
                     for key, words in (("any", "some exploration scale"), ("all", "every exploration scale"))]
            lines += ["", f"{explorer.upper()}: exploration collapsed: " + "; ".join(parts)]
    for key, sentence in (("first_evaluation", _first_evaluation_sentence), ("catch_held", _catch_held_sentence),
                          ("kept", _kept_sentence)):
        lines += [line for explorer, stats in result["explorers"].items() if stats.get(key)
                  for line in ("", f"{explorer.upper()}: {sentence(stats)}")]
    lines += ["", "Cells: percent of runs whose best / final deterministic evaluation reached the level, with its "
              "95 % Wilson interval; the paper's count out of 100 runs where it states one. A − B: the "
              "difference in percentage points with its 95 % bootstrap interval over runs; * where the interval "
              "excludes 0."]
    path.write_text("\n".join(lines) + "\n")


def _first_evaluation_sentence(stats: dict) -> str:
    first, n = stats["first_evaluation"], stats["runs"]
    return (f"at the first evaluation, after {first['update']} updates, a catch (R ≥ -1.1) in "
            f"{_percent(first['reached']['-1.1'] / n)} % of runs and a good catch (R ≥ -1.0) in "
            f"{_percent(first['reached']['-1.0'] / n)} %; at the final one {_percent(stats['final']['-1.1'] / n)} % "
            f"and {_percent(stats['final']['-1.0'] / n)} %")


def _catch_held_sentence(stats: dict) -> str:
    held = stats["catch_held"]
    return (f"once at a catch: of the {held['runs']} runs whose evaluation reached a catch (R ≥ -1.1) before the "
            f"last, the evaluations after the first such one are catches too in {_percent(held['share'])} % on average")


def _kept_sentence(stats: dict) -> str:
    k = stats["kept"]
    return (f"level kept: the best mean of {k['window']} consecutive evaluations lies {k['drop'][1]:.2f} above the "
            f"mean of the last {k['window']} in the median run (quartiles {k['drop'][0]:.2f}-{k['drop'][2]:.2f}); "
            f"that mean reached a catch (R ≥ -1.1) at some point in {_percent(k['catch_some_window'] / k['runs'])} % "
            f"of runs and at the end in {_percent(k['catch_last_window'] / k['runs'])} %")


def mean_curve(by_run: dict[int, dict]) -> tuple[list[int], list[tuple[float, float, float]]]:
    """Updates (1-based) with evaluations, and per update the mean return over runs with its
    95 % bootstrap interval."""
    from sde_torchrl.utils.intervals import bootstrap_interval

    updates = sorted({u for run in by_run.values() for u, _ in run["evals"]})
    curve = []
    for update in updates:
        values = [r for run in by_run.values() for u, r in run["evals"] if u == update]
        curve.append(tuple(bootstrap_interval(values, resamples=2000)))
    return [u + 1 for u in updates], curve


def plot(runs: dict[str, dict[int, dict]], result: dict, path: Path, title: str) -> None:
    """Left: mean evaluation curves with 95 % bands; right: percent of runs reaching each level
    (best evaluated policy) with 95 % intervals, and the paper's where it states them."""
    with saved_figure(path, 1, 2, figsize=(9, 3.4)) as (_, (left, right)):
        _plot_panels(runs, result, left, right, title)


def _plot_panels(runs: dict[str, dict[int, dict]], result: dict, left, right, title: str) -> None:
    """The two panels of :func:`plot`, drawn on the axes ``left`` and ``right``."""
    labels = [str(level) for level in LEVELS]
    shifts = [0.12 * (i - (len(runs) - 1) / 2) for i in range(len(runs))]
    for shift, (explorer, by_run) in zip(shifts, sorted(runs.items()), strict=True):
        line = style(explorer)
        x, curve = mean_curve(by_run)
        left.plot(x, [m for m, _, _ in curve], label=explorer.upper(), **line)
        left.fill_between(x, [lo for _, lo, _ in curve], [hi for _, _, hi in curve], color=line.get("color"),
                          alpha=0.2)
        stats = result["explorers"][explorer]
        fraction = [100 * stats["best"][f"{level}"] / stats["runs"] for level in LEVELS]
        low = [100 * stats["best_interval"][f"{level}"][0] for level in LEVELS]
        high = [100 * stats["best_interval"][f"{level}"][1] for level in LEVELS]
        positions = [i + shift for i in range(len(LEVELS))]
        right.errorbar(positions, fraction, yerr=[[max(f - lo, 0) for f, lo in zip(fraction, low, strict=True)],
                                                  [max(hi - f, 0) for f, hi in zip(fraction, high, strict=True)]],
                       marker="o", capsize=3, label=f"{explorer.upper()} ({stats['runs']} runs)", **line)
        paper = [(i, stats["paper"][f"{level}"]) for i, level in enumerate(LEVELS) if f"{level}" in stats["paper"]]
        if paper:
            right.scatter([i for i, _ in paper], [v for _, v in paper], marker="x", s=60, color=line.get("color"),
                          label=f"{explorer.upper()}, paper", zorder=3)
    left.set(xlabel="policy updates", ylabel="deterministic return R (mean reward)", title=title)
    right.set(xlabel="level: runs with R ≥ level", ylabel="% of runs (best evaluation)",
              title="runs reaching a level (95 % CI)", xticks=range(len(LEVELS)), xticklabels=labels, ylim=(-3, 103))
    left.legend(loc="lower right")
    right.legend(fontsize=7)


def main(argv: list[str] | None = None, estimator: str = "reinforce",
         prog: str = f"python -m {__spec__.name}") -> int:
    """Writes the figure and its tables; returns the exit code: 0, or :data:`~analysis.sweeps.EXIT_REFUSED`
    for sweeps it cannot be made from (:class:`Refused`, no run of the estimator), once their line
    ``error: ...`` is on stderr."""
    parser = argparse.ArgumentParser(prog=prog, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sweeps", nargs="+", type=Path, help="sweep or run directories (shards)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--estimator", choices=sorted(FIGURE), default=estimator)
    args = parser.parse_args(argv)
    try:
        runs = load_runs(args.sweeps, args.estimator)
        if not runs:
            raise Refused(f"no {args.estimator} runs under {[str(s) for s in args.sweeps]}")
        initial = load_per_run(args.sweeps, args.estimator, "initial.json", "initial_eval_return")
        final_policy = load_per_run(args.sweeps, args.estimator, "final_policy.json", "final_policy_return")
        result = report(runs, args.estimator, initial, final_policy)
        evaluated = final_policy_episodes(args.sweeps)
        behaviours = behaviour_counts(args.sweeps, args.estimator)
    except Refused as refused:
        print(f"error: {refused}", file=sys.stderr)
        return EXIT_REFUSED
    args.out.mkdir(parents=True, exist_ok=True)
    name = FIGURE[args.estimator]
    if evaluated is not None:
        result["final_policy"] = {"episodes": evaluated[0], "seed": evaluated[1]}
    if behaviours:
        result["behaviours"] = behaviours
    write_page_json(args.out / f"{name}.json", result, indent=2)
    write_markdown(result, args.out / f"{name}.md")
    method = "REINFORCE settings" if args.estimator == "all" else args.estimator.upper()
    plot(runs, result, args.out / f"{name}.png", f"ball catching, {method}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
