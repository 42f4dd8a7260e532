"""The PPO benchmark's report: a folder of runs as a table (final return and speed per method, SDE
against SB3 gSDE with bootstrap intervals over seeds) and a plot of the training curves."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from analysis.benchmarks.bench_ppo.build import ENV_ID, METHODS
from analysis.benchmarks.common import curve_band
from analysis.figures import ratio_of_means, saved_figure
from sde_torchrl.utils.intervals import bootstrap_interval


def load_runs(folder: Path) -> dict[str, list[dict]]:
    """The runs of a folder by method (``<method>_seed<k>.json``)."""
    runs: dict[str, list[dict]] = {m: [] for m in METHODS}
    for path in sorted(folder.glob("*_seed*.json")):
        data = json.loads(path.read_text())
        runs[data["method"]].append(data)
    if not any(runs.values()):
        raise SystemExit(f"bench_ppo: no <method>_seed<k>.json runs in {folder}: "
                         "run `python -m analysis.benchmarks.bench_ppo run` first")
    return runs


def report(folder: Path, out: Path) -> str:
    """Write ``bench_ppo.md``, ``bench_ppo.json`` and ``bench_ppo.png`` from a folder of runs; return
    the table."""
    runs = load_runs(folder)
    names = {"plain": "TorchRL PPO, Gaussian", "sde": "TorchRL PPO, SDE (ours)", "sb3": "SB3 PPO, gSDE",
             "sb3_gauss": "SB3 PPO, Gaussian"}
    for method in ("plain", "sde"):
        if runs[method] and all(r.get("compiled") for r in runs[method]):
            names[method] += ", compiled update"
    rows, stats = [], {}
    for method in METHODS:
        if not runs[method]:
            continue
        finals = np.array([r["final_return_mean"] for r in runs[method]])
        speed = np.array([r["env_steps_per_s"] for r in runs[method]])
        stats[method] = {"final": finals.tolist(), "speed": speed.tolist(), "steps": runs[method][0]["env_steps"]}
        rows.append(f"| {names[method]} | {len(finals)} | {stats[method]['steps']:,} | {finals.mean():.0f} ± "
                    f"{finals.std(ddof=1) if len(finals) > 1 else 0:.0f} | {', '.join(f'{f:.0f}' for f in finals)} "
                    f"| {speed.mean():.0f} |")
    lines = ["| method | seeds | env steps | final deterministic return (mean ± sd over seeds) | per seed "
             "| env steps / s |", "| --- | --- | --- | --- | --- | --- |", *rows]
    if "sde" in stats and "sb3" in stats:
        ratios = {}
        for quantity in ("final", "speed"):
            ratios[quantity] = bootstrap_interval((stats["sde"][quantity], stats["sb3"][quantity]), ratio_of_means)
        stats["sde_over_sb3"] = {q: ratio._asdict() for q, ratio in ratios.items()}
        ret, spd = ratios["final"], ratios["speed"]
        lines += ["", f"SDE / SB3 gSDE: final return {ret.estimate:.2f}× [{ret.low:.2f}, {ret.high:.2f}] "
                      f"(target ≥ 0.90), env steps per second {spd.estimate:.2f}× [{spd.low:.2f}, {spd.high:.2f}] "
                      "(target ≥ 0.8); [95 % bootstrap intervals over seeds]."]
    table = "\n".join(lines) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_ppo.md").write_text(table)
    (out / "bench_ppo.json").write_text(json.dumps(stats, indent=1))
    _plot(runs, names, out / "bench_ppo.png")
    return table


def _plot(runs: dict[str, list[dict]], names: dict[str, str], path: Path) -> None:
    bin_steps = 50_000
    with saved_figure(path, figsize=(6.4, 4)) as (_, ax):
        for method, method_runs in runs.items():
            if not method_runs:
                continue
            total = max(r["env_steps"] for r in method_runs)
            x, mean, low, high = curve_band(method_runs, bin_steps, total)
            ax.plot(x, mean, label=f"{names[method]} ({len(method_runs)} seeds)")
            if len(method_runs) > 1:
                ax.fill_between(x, low, high, alpha=0.2)
        ax.set_xlabel("env steps")
        ax.set_ylabel("training episode return (raw)")
        ax.set_title(f"PPO on {ENV_ID} (rl-zoo settings); band: min-max over seeds", fontsize=9)
        ax.legend()
