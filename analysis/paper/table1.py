"""Reproduce the function-minimisation results: Table 1, Fig. 2 and Fig. 3 of the paper.

Runs the sweeps ``noise_sweep`` and ``episode_length_sweep`` (``analysis/conf/experiment/``) and
``minimize2d_mlp`` (``conf/experiment/``) (each job trains 30 runs side by side, on the authors' task with the
learner that ``analysis/selection/learner_search.py`` chose) on a pool of worker processes (``analysis/runner.py``:
into ``DIR/runs``, a finished job without its checkpoint, which only made reading it slower; a rerun
skips the finished jobs and resumes the others), or reads finished run
directories, and writes into ``--out DIR``: ``table1.json``, ``table1.md`` (every cell beside the
paper's, and the checks of :func:`checks`), ``fig2.png``, ``fig3_left.png`` and ``fig3_right.png``.

Every count, speed-up and plateau time carries a 95 % percentile-bootstrap interval over runs
(:func:`sde_torchrl.utils.intervals.bootstrap_interval`, 10,000 resamples, seed 0): a cell reads
``1,850 [1,620, 2,110]``. A difference is called significant when the bootstrap interval of the
ratio of the two methods' mean counts excludes 1, and ours differs significantly from the paper's
when the paper's count lies outside our interval (the paper gives no spread of its own).

Added method, beyond the paper: **GPOMDP + SDE**, the SDE jobs of the two 1-D sweeps again with
``estimator=gpomdp``. Its learner, by the rule of ``analysis/selection/learner_search.py``, which chooses
ONE learner for all the methods compared and never tunes one method alone, is that learner
unchanged (plain scores, per-run norm bound 100, N = 10, α = 0.002, summed return, the sweeps'
budget). Rerunning the search with GPOMDP among the methods would let GPOMDP's runs change REX's
and SDE's learner, and a search for GPOMDP alone is what the rule forbids. (Written down and
committed before any Table 1 result of GPOMDP was seen.)

Added method, beyond the paper: **PGPE** (``explorer=pgpe estimator=pgpe``, Sehnke et al. 2010), the SDE
jobs of the two 1-D sweeps again with PGPE's explorer and estimator. Its settings follow the same
rule, written down and committed before any Table 1 result of PGPE was seen (none was run):

1. The learner is the one ``analysis/selection/learner_search.py`` chose for all methods, unchanged: plain
   gradients (``estimator.variance_weighted=false``: PGPE's likelihood-ratio gradient itself, not
   the paper's ``α_i = α σ_i²`` step, which is the counterpart of the variance-weighted scores the
   search did not choose), the per-run norm bound 100, N = 10 episodes per update, α = 0.002, the
   summed return, the sweeps' budget (2,000 updates) and stop rule.
2. PGPE's own options take their standard or SDE-matched values, fixed here: symmetric sampling
   (the standard PGPE variant, section 2.3: 5 pairs μ ± ε per update), σ learned, σ₀ = e⁻² ≈ 0.135
   per parameter (``explorer.init_param=-2``, SDE's σ̂₀: on the linear controller PGPE's first
   episodes are then distributed exactly as SDE's, ``(θ + σ ξ) x``), the batch's mean return as
   baseline (the estimator's only baseline).
3. Nothing of PGPE is tuned, and the search is not rerun with PGPE among the methods (its runs
   would change REX's and SDE's learner); if PGPE misses R_lim within the budget in some runs,
   the table reports them as not converged.

Usage:
    python -m analysis.paper.table1 --out results/table1              # run everything, then report
    python -m analysis.paper.table1 --out results/table1 --from DIR   # report on finished runs
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import math
import os
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from analysis.figures import bounds, ratio_of_means, saved_figure, style
from analysis.runner import TrainJob, run_train_jobs
from analysis.sweeps import finished_jobs

EXPERIMENTS = ("noise_sweep", "episode_length_sweep", "minimize2d_mlp")
#: Methods of the 1-D table: the paper's two, then the added GPOMDP + SDE and PGPE.
METHODS = ("rex", "sde", "sde_gpomdp", "pgpe")
LABELS = {"rex": "REX", "sde": "SDE", "sde_gpomdp": "SDE + GPOMDP", "pgpe": "PGPE"}
#: Added methods: the overrides that turn each SDE job of the 1-D sweeps into theirs (replacing
#: the SDE job's choice for the same group).
ADDED = {"sde_gpomdp": ["estimator=gpomdp"], "pgpe": ["explorer=pgpe", "estimator=pgpe"]}
#: Comparisons with a ratio of mean episodes (``slow / fast``) and its interval: row key → (slow, fast).
RATIOS = {"speedup": ("rex", "sde"), "gpomdp_ratio": ("sde", "sde_gpomdp"), "pgpe_ratio": ("pgpe", "sde")}
#: The confidence level and bootstrap resamples of every interval.
LEVEL, RESAMPLES = 0.95, 10_000
SWEEP_NAMES = {"noise_sweep": "noise", "episode_length_sweep": "episode_length"}
#: Table 1 of the paper: (sweep, σ_noise, EL) → (R_lim, REX episodes, SDE episodes).
PAPER = {
    ("episode_length", 0.5, 5): (-1.8, 9450, 3350), ("episode_length", 0.5, 15): (-1.8, 9150, 1850),
    ("episode_length", 0.5, 30): (-1.8, 9700, 1050), ("episode_length", 0.5, 45): (-1.8, 8800, 650),
    ("episode_length", 0.5, 60): (-1.8, 8050, 500), ("noise", 0.5, 15): (-1.6, 9950, 2000),
    ("noise", 1.0, 15): (-1.6, 9850, 1400), ("noise", 1.5, 15): (-1.6, 7700, 900),
}
#: Fig. 3 right of the paper: REX "stuck near R = -70" after 15,000 episodes; SDE reaches -70
#: after about 1,000 episodes.
PAPER_MLP = {"rex_plateau": -70.0, "sde_episodes_to_plateau": 1000}
#: Updates averaged for the 2-D MLP's curves and final plateau.
SMOOTH = 10

log = logging.getLogger("table1")


# --------------------------------------------------------------------------- running jobs

def sweep_jobs(experiment: str) -> list[list[str]]:
    """The override lists of every job in ``experiment``'s Hydra sweeper params."""
    from sde_torchrl.config.compose import compose

    cfg = compose([f"+experiment={experiment}"], return_hydra_config=True)
    params = {key: str(values).split(",") for key, values in cfg.hydra.sweeper.params.items()}
    return [[f"{key}={value}" for key, value in zip(params, combo, strict=True)]
            for combo in itertools.product(*params.values())]


def jobs(runs_dir: Path, extra: list[str]) -> list[TrainJob]:
    """Every job of :data:`EXPERIMENTS` (with the :data:`ADDED` methods' variants of the 1-D
    sweeps' SDE jobs), each in ``runs_dir/<experiment>__<overrides>``, ``extra`` overrides last."""
    found = []
    for experiment in EXPERIMENTS:
        for overrides in sweep_jobs(experiment):
            variants = [overrides]
            if experiment in SWEEP_NAMES and "explorer=sde" in overrides:
                variants += [_variant(overrides, added) for added in ADDED.values()]
            for variant in variants:
                name = experiment + "__" + "_".join(o.replace("=", "-") for o in variant)
                found.append(TrainJob(name, (f"+experiment={experiment}", *variant, *extra), runs_dir / name,
                                      _expected_cost(experiment, variant + extra)))
    return found


def _variant(overrides: list[str], added: list[str]) -> list[str]:
    """``overrides`` with ``added`` appended, dropping the overrides of the groups it sets."""
    groups = {o.split("=", 1)[0] for o in added}
    return [o for o in overrides if o.split("=", 1)[0] not in groups] + added


def _expected_cost(experiment: str, overrides: list[str]) -> float:
    if experiment == "minimize2d_mlp":
        return 1e9
    length = next((int(o.split("=")[1]) for o in overrides if o.startswith("env.episode_length=")), 15)
    factor = 4 if "explorer=rex" in overrides else 5 if "explorer=pgpe" in overrides else \
        2 if "estimator=gpomdp" in overrides else 1
    return length * factor


# -------------------------------------------------------------------------- reading runs

def load_runs(directory: Path) -> list[dict]:
    """Every finished run under ``directory``: its summary and per-update mean returns."""
    runs = []
    for job in finished_jobs(directory):  # refuses a job not finished or not started, by name
        if job.summary.get("experiment") not in EXPERIMENTS:
            continue
        curves = job.values("return_mean")
        runs.append(job.summary | {"curves": [curves[r] for r in sorted(curves)]})  # [runs][updates]
    return runs


def _method(summary: dict) -> str:
    """``rex``, ``sde`` or an added method (:data:`ADDED`) from a run's labels."""
    return "sde_gpomdp" if summary.get("estimator") == "gpomdp" else summary["explorer"]


def _setting(summary: dict) -> tuple[str, float, int]:
    env = summary["config"]["env"]
    return SWEEP_NAMES[summary["experiment"]], float(env["noise_std"]), int(env["episode_length"])


def _interval(values, statistic=None) -> list[float]:
    """``[low, high]`` of the 95 % bootstrap interval (:data:`LEVEL`, :data:`RESAMPLES`, seed 0)."""
    from sde_torchrl.utils.intervals import bootstrap_interval

    kwargs = {} if statistic is None else {"statistic": statistic}
    return bounds(bootstrap_interval(values, level=LEVEL, resamples=RESAMPLES, seed=0, **kwargs))


def table_rows(runs: list[dict]) -> list[dict]:
    """One row per (sweep, σ_noise, EL): mean episodes to ``R_lim`` per method (over the runs that
    reached it) with 95 % bootstrap intervals over those runs, REX/SDE speed-up, SDE's
    REINFORCE/GPOMDP ratio and PGPE/SDE ratio with intervals (:data:`RATIOS`; a ratio whose
    interval excludes 1 is significant)."""
    by_setting: dict[tuple, dict[str, dict]] = {}
    for summary in runs:
        if summary["experiment"] in SWEEP_NAMES:
            by_setting.setdefault(_setting(summary), {})[_method(summary)] = summary
    rows = []
    for setting in sorted(by_setting, key=lambda s: (s[0] != "noise", s[1], s[2])):
        sweep, noise, length = setting
        row = {"sweep": sweep, "sigma_noise": noise, "episode_length": length}
        reached_by = {}
        for method in METHODS:
            summary = by_setting[setting].get(method)
            if summary is None:
                continue
            row["r_lim"] = summary["settings"]["r_lim"]
            episodes = summary["episodes_to_threshold"]
            reached = reached_by[method] = [e for e in episodes if e is not None]
            row[f"{method}_episodes"] = statistics.mean(reached) if reached else None
            row[f"{method}_ci"] = _interval(reached) if reached else None
            row[f"{method}_spread"] = {
                "std": statistics.pstdev(reached) if reached else None,
                "median": statistics.median(reached) if reached else None,
                "min": min(reached, default=None), "max": max(reached, default=None),
                "runs": len(episodes), "not_converged": len(episodes) - len(reached),
            }
        for key, (slow, fast) in RATIOS.items():
            if row.get(f"{slow}_episodes") and row.get(f"{fast}_episodes"):
                row[key] = row[f"{slow}_episodes"] / row[f"{fast}_episodes"]
                row[f"{key}_ci"] = _interval((reached_by[slow], reached_by[fast]), ratio_of_means)
                row[f"{key}_significant"] = not row[f"{key}_ci"][0] <= 1 <= row[f"{key}_ci"][1]
        paper = PAPER.get(setting)
        if paper:
            row["paper"] = {"r_lim": paper[0], "rex_episodes": paper[1], "sde_episodes": paper[2],
                            "speedup": paper[1] / paper[2]}
            row["paper_outside_ci"] = {
                key: not row[f"{key}_ci"][0] <= row["paper"][f"{key}_episodes" if key != "speedup" else key]
                <= row[f"{key}_ci"][1]
                for key in ("rex", "sde", "speedup") if row.get(f"{key}_ci")}
        rows.append(row)
    return rows


def _mean_curve(curves: list[list[float]], smooth: int = 1) -> tuple[list[float], list[float]]:
    """Mean and std over runs per update (each run's curve smoothed over ``smooth`` updates)."""
    columns = list(zip(*[_window_means(c, smooth) for c in curves], strict=False))
    return [_window_means(c, len(c))[-1] for c in columns], [statistics.pstdev(c) for c in columns]


def _window_means(values: Sequence[float], window: int) -> list[float]:
    """The mean of each value and the ``window - 1`` before it (fewer at the start), each as
    :func:`statistics.mean` gives it: the exact mean, rounded once. Finite floats are summed
    exactly as integers (each a multiple of the smallest power of two among them), so that
    every mean costs one division; with a non-finite value, :func:`statistics.mean` itself.

    Examples:
        >>> _window_means([0.1, 0.2, 0.3, 0.4], 2) == [statistics.mean(w) for w in ([0.1], [0.1, 0.2], [0.2, 0.3],
        ...                                                                          [0.3, 0.4])]
        True
    """
    if not all(map(math.isfinite, values)):
        return [statistics.mean(values[max(0, i - window + 1): i + 1]) for i in range(len(values))]
    ratios = [float(v).as_integer_ratio() for v in values]
    unit = max((d for _, d in ratios), default=1)  # every denominator is a power of two: all divide it
    sums = list(itertools.accumulate((n * (unit // d) for n, d in ratios), initial=0))
    return [(sums[i + 1] - sums[max(0, i - window + 1)]) / (unit * min(i + 1, window)) for i in range(len(values))]


def mlp_summary(runs: list[dict]) -> dict | None:
    """2-D MLP: REX's final plateau, episodes each method needs to reach it, final returns."""
    mlp = {s["explorer"]: s for s in runs if s["experiment"] == "minimize2d_mlp"}
    if set(mlp) != {"sde", "rex"}:
        return None
    per_update = mlp["rex"]["settings"]["episodes_per_update"]
    means = {e: _mean_curve(s["curves"], SMOOTH)[0] for e, s in mlp.items()}
    tail = max(1, len(means["rex"]) // 10)
    plateau = statistics.mean(means["rex"][-tail:])

    def first_reaching(curve):
        index = next((i for i, v in enumerate(curve) if v >= plateau), None)
        return None if index is None else (index + 1) * per_update

    result = {
        "rex_plateau": plateau,
        "episodes_to_rex_plateau": {e: first_reaching(means[e]) for e in ("sde", "rex")},
        "final_mean_return": {e: statistics.mean(means[e][-tail:]) for e in ("sde", "rex")},
        "episodes": len(means["rex"]) * per_update, "runs": mlp["rex"]["runs"],
        "smoothing_updates": SMOOTH,
    }
    reached = result["episodes_to_rex_plateau"]
    if reached["sde"] and reached["rex"]:
        result["plateau_speedup"] = reached["rex"] / reached["sde"]
    result["intervals"] = _mlp_intervals({e: _smoothed(s["curves"], SMOOTH) for e, s in mlp.items()}, per_update, tail)
    return result


#: Resamples of the 2-D MLP's curve statistics (each resample averages 30 curves of 1,500 updates).
MLP_RESAMPLES = 2_000


def _smoothed(curves: list[list[float]], smooth: int):
    """Each run's curve averaged over its last ``smooth`` updates (fewer at the start), ``[runs, updates]``."""
    import numpy as np

    values = np.asarray(curves, dtype=float)
    total = np.cumsum(values, axis=1)
    lagged = np.concatenate([np.zeros((len(values), smooth)), total[:, :-smooth]], axis=1)[:, :values.shape[1]]
    return (total - lagged) / np.minimum(np.arange(1, values.shape[1] + 1), smooth)


def _mlp_intervals(smoothed: dict, per_update: int, tail: int) -> dict:
    """95 % bootstrap intervals over runs of the 2-D MLP's REX plateau, the episodes each method
    needs to reach it (the plateau recomputed in each resample), their ratio, and the final
    mean returns. The runs are resampled as indices into the smoothed curves."""
    import numpy as np

    from sde_torchrl.utils.intervals import bootstrap_interval

    def mean_curves(indices, curves):
        runs = len(curves)
        counts = (indices.astype(int)[..., :, None] == np.arange(runs)).sum(-2)  # [..., runs]
        return counts @ curves / indices.shape[-1]

    def reaching(rex_indices, sde_indices):
        rex = mean_curves(rex_indices, smoothed["rex"])
        plateau = rex[..., -tail:].mean(-1)
        result = {"rex_plateau": plateau}
        for method, curve in (("rex", rex), ("sde", mean_curves(sde_indices, smoothed["sde"]))):
            above = curve >= plateau[..., None]
            result[method] = np.where(above.any(-1), (above.argmax(-1) + 1) * per_update, np.inf)
        return result

    def speedup(reached):
        return reached["rex"] / reached["sde"]

    def interval(statistic, values):
        return bounds(bootstrap_interval(values, statistic, LEVEL, MLP_RESAMPLES, seed=0))

    indices = (np.arange(len(smoothed["rex"])), np.arange(len(smoothed["sde"])))
    return {
        "rex_plateau": interval(lambda r, s: reaching(r, s)["rex_plateau"], indices),
        "episodes_to_rex_plateau": {m: interval(lambda r, s, m=m: reaching(r, s)[m], indices) for m in ("sde", "rex")},
        "plateau_speedup": interval(lambda r, s: speedup(reaching(r, s)), indices),
        "final_mean_return": {m: _interval(smoothed[m][:, -tail:].mean(-1)) for m in ("sde", "rex")},
        "resamples": MLP_RESAMPLES,
    }


# ------------------------------------------------------------------------------- writing

def checks(rows: list[dict], mlp: dict | None) -> dict:
    """The checks the reproduction of Table 1 and Figs. 2-3 is held to: all runs converged, speed-up growing with
    EL (EL 60 ≥ 3× EL 5) and noise (σ 1.5 > σ 0.5), counts within a factor 2 of the paper's,
    and the 2-D MLP's SDE reaching REX's plateau ≥ 5× sooner and ending higher."""
    def row(sweep, noise, length):
        return next((r for r in rows if (r["sweep"], r["sigma_noise"], r["episode_length"]) == (sweep, noise, length)),
                    {})

    def within(ours, paper):
        return ours is not None and paper / 2 <= ours <= 2 * paper

    within_2 = [r for r in rows if "paper" in r and within(r.get("rex_episodes"), r["paper"]["rex_episodes"])
                and within(r.get("sde_episodes"), r["paper"]["sde_episodes"])]
    speed = {key: row(*key).get("speedup") for key in
             (("episode_length", 0.5, 5), ("episode_length", 0.5, 60), ("noise", 0.5, 15), ("noise", 1.5, 15))}
    result = {
        "all_runs_converged": all(r.get(f"{e}_spread", {}).get("not_converged", 1) == 0
                                  for r in rows for e in ("rex", "sde")),
        "settings_within_factor_2": len(within_2), "settings": len(rows),
        "speedup_el60_over_el5": (speed[("episode_length", 0.5, 60)] / speed[("episode_length", 0.5, 5)]
                                  if all(speed.values()) else None),
        "speedup_grows_with_noise": (speed[("noise", 1.5, 15)] > speed[("noise", 0.5, 15)]
                                     if all(speed.values()) else None),
    }
    if mlp:
        result["mlp_plateau_speedup"] = mlp.get("plateau_speedup")
        result["mlp_sde_ends_higher"] = mlp["final_mean_return"]["sde"] > mlp["final_mean_return"]["rex"]
    return result


def _fmt(value, digits=0):
    return "—" if value is None else f"{value:.{digits}f}"


def _cell(value, interval, digits=0) -> str:
    """``1,850 [1,620, 2,110]``: a value and its interval, or ``—``."""
    if value is None:
        return "—"
    text = f"{value:,.{digits}f}"
    return text if interval is None else f"{text} [{interval[0]:,.{digits}f}, {interval[1]:,.{digits}f}]"


def _label(row: dict) -> str:
    return f"σ {row['sigma_noise']}" if row["sweep"] == "noise" else f"EL {row['episode_length']}"


def significance_lines(rows: list[dict]) -> list[str]:
    """Which differences are significant at 95 %: methods (ratio interval excluding 1) and ours
    against the paper's (the paper's count outside our interval)."""
    def listed(predicate):
        found = [_label(r) for r in rows if predicate(r)]
        return f"{len(found)} of {len(rows)}" + (f" ({', '.join(found)})" if found else "")

    def paper_outside(key):
        return listed(lambda r: r.get("paper_outside_ci", {}).get(key, False))

    def compared(key):
        """(settings with the ratio, significantly above 1, significantly below 1)."""
        return (len([r for r in rows if r.get(key) is not None]),
                listed(lambda r: r.get(f"{key}_significant") and r[key] > 1),
                listed(lambda r: r.get(f"{key}_significant") and r[key] < 1))

    ratios, faster, slower = compared("gpomdp_ratio")
    pgpe_ratios, sde_faster, pgpe_faster = compared("pgpe_ratio")
    return [
        "Significance (95 %; `†` in the table: the paper's number lies outside our interval):",
        "",
        f"- SDE faster than REX (speed-up interval above 1): {listed(lambda r: r.get('speedup_significant'))}.",
        f"- Paper's REX count outside our interval: {paper_outside('rex')}; SDE: {paper_outside('sde')}; "
        f"speed-up: {paper_outside('speedup')}.",
        f"- SDE + GPOMDP against SDE + REINFORCE (interval of REINFORCE's / GPOMDP's mean episodes, "
        f"{ratios} settings): GPOMDP significantly faster in {faster}; significantly slower in {slower}.",
        f"- PGPE against SDE (interval of PGPE's / SDE's mean episodes over the runs that reached R_lim, "
        f"{pgpe_ratios} settings): SDE significantly faster in {sde_faster}; PGPE significantly faster in "
        f"{pgpe_faster}.",
    ]


def write_markdown(rows: list[dict], mlp: dict | None, path: Path, wall_s: float | None = None) -> None:
    """The paper's Table 1 layout, ours (with 95 % bootstrap intervals over runs) beside the
    paper's, the added SDE + GPOMDP and PGPE, which differences are significant, the 2-D MLP, the checks."""
    def paper_mark(row, key):
        return " †" if row.get("paper_outside_ci", {}).get(key) else ""

    lines = [
        "| sweep | σ_noise | EL | R_lim (ours / paper) | REX: ours [95 % CI] / paper | SDE: ours [95 % CI] / paper "
        "| speed-up REX/SDE: ours [95 % CI] / paper | SDE + GPOMDP [95 % CI] "
        "| SDE: REINFORCE/GPOMDP episodes [95 % CI] | PGPE [95 % CI] | PGPE/SDE episodes [95 % CI] "
        "| not converged REX / SDE / SDE + GPOMDP / PGPE |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for row in rows:
        paper = row.get("paper", {})
        lines.append(
            f"| {row['sweep']} | {row['sigma_noise']} | {row['episode_length']} "
            f"| {_fmt(row.get('r_lim'), 2)} / {_fmt(paper.get('r_lim'), 1)} "
            f"| {_cell(row.get('rex_episodes'), row.get('rex_ci'))} / {_cell(paper.get('rex_episodes'), None)}"
            f"{paper_mark(row, 'rex')} "
            f"| {_cell(row.get('sde_episodes'), row.get('sde_ci'))} / {_cell(paper.get('sde_episodes'), None)}"
            f"{paper_mark(row, 'sde')} "
            f"| {_cell(row.get('speedup'), row.get('speedup_ci'), 2)} / {_fmt(paper.get('speedup'), 2)}"
            f"{paper_mark(row, 'speedup')} "
            f"| {_cell(row.get('sde_gpomdp_episodes'), row.get('sde_gpomdp_ci'))} "
            f"| {_cell(row.get('gpomdp_ratio'), row.get('gpomdp_ratio_ci'), 2)} "
            f"| {_cell(row.get('pgpe_episodes'), row.get('pgpe_ci'))} "
            f"| {_cell(row.get('pgpe_ratio'), row.get('pgpe_ratio_ci'), 2)} "
            f"| {' / '.join(str(row.get(f'{m}_spread', {}).get('not_converged', '—')) for m in METHODS)} |"
        )
    lines += ["", *significance_lines(rows)]
    if mlp:
        reached, intervals = mlp["episodes_to_rex_plateau"], mlp["intervals"]
        lines += [
            "",
            f"2-D MLP ({mlp['runs']} runs, {mlp['episodes']} episodes; 95 % bootstrap intervals over runs, "
            f"{intervals['resamples']:,} resamples): REX's final plateau "
            f"{_cell(mlp['rex_plateau'], intervals['rex_plateau'], 2)} reached after "
            f"{_cell(reached['sde'], intervals['episodes_to_rex_plateau']['sde'])} episodes by SDE and "
            f"{_cell(reached['rex'], intervals['episodes_to_rex_plateau']['rex'])} by REX "
            f"(×{_cell(mlp.get('plateau_speedup'), intervals['plateau_speedup'], 1)}); final mean return SDE "
            f"{_cell(mlp['final_mean_return']['sde'], intervals['final_mean_return']['sde'], 2)}, REX "
            f"{_cell(mlp['final_mean_return']['rex'], intervals['final_mean_return']['rex'], 2)} "
            f"(summed return; paper: REX stuck near {PAPER_MLP['rex_plateau']:.0f}, SDE there after about "
            f"{PAPER_MLP['sde_episodes_to_plateau']:,} episodes).",
        ]
    c = checks(rows, mlp)
    lines += [
        "",
        f"Checks: every run of every job reached R_lim: {c['all_runs_converged']}; settings with both counts "
        f"within a factor 2 of the paper's: {c['settings_within_factor_2']} of {c['settings']}; speed-up EL 60 / "
        f"EL 5: {_fmt(c['speedup_el60_over_el5'], 2)} (paper 5.71); speed-up σ 1.5 > σ 0.5: "
        f"{c['speedup_grows_with_noise']}.",
    ]
    if wall_s is not None:
        lines.append(f"Wall time of `python -m analysis.paper.table1`: {wall_s:.0f} s.")
    path.write_text("\n".join(lines) + "\n")


def plot_convergence(runs: list[dict], sweep: str, path: Path) -> None:
    """One panel per setting of ``sweep``: median and quartiles of the returns over runs, REX, SDE,
    SDE + GPOMDP and PGPE (a mean would follow single REX runs on excursions to returns of -10³ and below)."""
    chosen = sorted((s for s in runs if SWEEP_NAMES.get(s["experiment"]) == sweep),
                    key=lambda s: _setting(s))
    settings = sorted({_setting(s) for s in chosen})
    with saved_figure(path, 1, len(settings), figsize=(3.2 * len(settings), 3.0), squeeze=False) as (_, axes):
        for ax, setting in zip(axes[0], settings, strict=True):
            for summary in (s for s in chosen if _setting(s) == setting):
                _plot_band(ax, summary, LABELS[_method(summary)], robust=True)
                ax.axhline(summary["settings"]["r_lim"], color="grey", lw=0.8, ls=":")
            label = f"σ_noise = {setting[1]}" if sweep == "noise" else f"EL = {setting[2]}"
            r_lim = next(s["settings"]["r_lim"] for s in chosen if _setting(s) == setting)
            ax.set(title=label, xlabel="episodes", xscale="log",
                   ylim=(_lower_limit(chosen, setting), 0.5 * r_lim))
        axes[0][0].set_ylabel("return R (median, quartiles)")
        axes[0][0].legend(loc="lower right")


def _lower_limit(chosen: list[dict], setting: tuple) -> float:
    starts = [statistics.mean(c[0] for c in s["curves"]) for s in chosen if _setting(s) == setting]
    return 1.5 * min(starts)


def _plot_band(ax, summary: dict, label: str, smooth: int = 1, robust: bool = False) -> None:
    """Mean ± std over runs per update, or with ``robust`` median and quartiles."""
    if robust:
        columns = list(zip(*summary["curves"], strict=False))
        quartiles = [statistics.quantiles(c, n=4, method="inclusive") for c in columns]
        centre, low, high = ([q[i] for q in quartiles] for i in (1, 0, 2))
    else:
        centre, std = _mean_curve(summary["curves"], smooth)
        low, high = [m - s for m, s in zip(centre, std, strict=True)], [m + s for m, s in zip(centre, std, strict=True)]
    per_update = summary["settings"]["episodes_per_update"]
    episodes = [(i + 1) * per_update for i in range(len(centre))]
    line = style(label)
    ax.plot(episodes, centre, label=label, **line)
    ax.fill_between(episodes, low, high, color=line["color"], alpha=0.2)


def plot_mlp(runs: list[dict], mlp: dict, path: Path) -> None:
    """Fig. 3 right: the 2-D MLP task, REX and SDE, with REX's final plateau."""
    with saved_figure(path, figsize=(5, 3.4)) as (_, ax):
        for summary in sorted((s for s in runs if s["experiment"] == "minimize2d_mlp"),
                              key=lambda s: s["explorer"]):
            _plot_band(ax, summary, LABELS[_method(summary)], SMOOTH)
        ax.axhline(mlp["rex_plateau"], color="grey", lw=0.8, ls=":", label="REX final plateau")
        start = min(statistics.mean(c[0] for c in s["curves"]) for s in runs
                    if s["experiment"] == "minimize2d_mlp")
        ax.set(xlabel="episodes", ylabel=f"mean return R ({SMOOTH}-update average)",
               title="2-D task, MLP with 18 parameters", ylim=(1.5 * start, 0))
        ax.legend(loc="lower right")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="where tables and figures go")
    parser.add_argument("--from", dest="source", type=Path,
                        help="read finished run directories instead of running the sweeps")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("overrides", nargs="*", help="extra config overrides for every job (e.g. runs=5)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")

    args.out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    source = args.source
    if source is None:
        source = args.out / "runs"
        if run_train_jobs(jobs(source, args.overrides), args.workers, keep_checkpoints=False):
            return 1  # the failed jobs are named in the log; a rerun resumes them
    runs = load_runs(source)
    if not runs:
        log.error("no finished runs under %s", source)
        return 1
    rows, mlp = table_rows(runs), mlp_summary(runs)
    wall_s = None if args.source else time.perf_counter() - start
    (args.out / "table1.json").write_text(json.dumps(
        {"rows": rows, "mlp2d": mlp, "paper_mlp2d": PAPER_MLP, "checks": checks(rows, mlp), "wall_s": wall_s},
        indent=2))
    write_markdown(rows, mlp, args.out / "table1.md", wall_s)
    plot_convergence(runs, "noise", args.out / "fig2.png")
    plot_convergence(runs, "episode_length", args.out / "fig3_left.png")
    if mlp:
        plot_mlp(runs, mlp, args.out / "fig3_right.png")
    log.info("wrote %s in %.0f s", args.out, time.perf_counter() - start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
