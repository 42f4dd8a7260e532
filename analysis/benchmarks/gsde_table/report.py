"""``report``: a folder of runs (:mod:`.run`) as the table, a page, a JSON and a plot per env.

Per cell (algorithm, env, noise) and side: the final deterministic return, mean ± sd over seeds;
ours against SB3 (the ratio of the means, or their difference when either mean is ≤ 0: a ratio of
returns on either side of zero means nothing); SDE − Gaussian on both sides; env steps per second,
ours ÷ SB3; each with a 95 % percentile-bootstrap interval over seeds
(:func:`~sde_torchrl.utils.intervals.bootstrap_interval`); the paper's numbers beside, where it
reports the cell (:data:`.paper.PAPER`). The plots: the evaluation return against env steps, mean over seeds with
the lowest and highest seed as a band, one panel per algorithm.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from analysis.benchmarks.gsde_table.cells import ALGORITHMS, ALL_ENVS, ENV_IDS, NOISES, Cell
from analysis.benchmarks.gsde_table.paper import PAPER, PAPER_SEEDS, paper_text
from analysis.benchmarks.gsde_table.run import MANIFEST, ours_dir, sb3_record
from analysis.figures import difference_of_means, ratio_of_means, saved_figure, write_page_json
from sde_torchrl.utils.intervals import Interval, bootstrap_interval

#: The sides of a cell.
SIDES = ("ours", "sb3")
NAMES = {"ours": "ours (TorchRL)", "sb3": "SB3"}
#: A run's name: the cell it belongs to.
RUN_NAME = re.compile(r"^(?P<algorithm>[a-z0-9]+)_(?P<env>[a-z0-9]+)_(?P<noise>[a-z]+)_seed(?P<seed>\d+)$")


def read_ours(path: Path) -> dict[str, Any] | None:
    """Our run of a cell: final evaluation, evaluation curve, env steps and speed; ``None`` if it
    has not finished (:func:`~sde_torchrl.jobs.run_dir.read_finished_run`)."""
    from sde_torchrl.jobs.run_dir import UnfinishedRunError, read_finished_run
    from sde_torchrl.utils.files import DamagedFileError

    try:
        finished = read_finished_run(path)
    except (UnfinishedRunError, DamagedFileError, FileNotFoundError):
        return None
    summary = finished.summary
    steps, updates = int(summary["env_steps"]), int(summary["updates_done"])
    (series,) = finished.series("eval_return").values()
    return {"final": float(summary["final_eval_return"][0]), "env_steps": steps, "wall_s": float(summary["wall_s"]),
            "speed": steps / float(summary["wall_s"]),
            "evals": [[(update + 1) * steps // updates, float(value)] for update, value in series]}


def read_sb3(path: Path) -> dict[str, Any] | None:
    """The SB3 run of a cell (its record), ``None`` if there is none."""
    if not path.exists():
        return None
    record = json.loads(path.read_text())
    return {"final": float(record["final_eval_return"]), "env_steps": int(record["env_steps"]),
            "wall_s": float(record["wall_s"]), "speed": float(record["env_steps_per_s"]), "evals": record["evals"]}


def load(folder: Path) -> tuple[dict[str, Any], dict[tuple[str, str, str], dict[str, dict[int, dict]]]]:
    """The folder's manifest and its runs: (algorithm, env, noise) → side → seed → run.

    Raises:
        SystemExit: the folder is not a table's folder, or holds no finished run.
    """
    manifest_path = folder / MANIFEST
    if not manifest_path.exists():
        raise SystemExit(f"gsde_table: {folder} has no {MANIFEST}: not a folder of `python -m "
                         "analysis.benchmarks.gsde_table run --out FOLDER`")
    manifest = json.loads(manifest_path.read_text())
    names = {p.name for p in (folder / "ours").glob("*") if p.is_dir()} | \
        {p.name.removesuffix(".json") for p in (folder / "sb3").glob("*.json")}
    runs: dict[tuple[str, str, str], dict[str, dict[int, dict]]] = {}
    for name in sorted(names):
        match = RUN_NAME.match(name)
        if match is None:
            continue
        cell = Cell(match["algorithm"], match["env"], match["noise"], int(match["seed"]))
        for side, run in (("ours", read_ours(ours_dir(folder, cell))), ("sb3", read_sb3(sb3_record(folder, cell)))):
            if run is not None:
                runs.setdefault((cell.algorithm, cell.env, cell.noise), {s: {} for s in SIDES})[side][cell.seed] = run
    if not runs:
        raise SystemExit(f"gsde_table: no finished run in {folder}")
    return manifest, runs


def compare(ours: list[float], theirs: list[float]) -> dict[str, Any]:
    """Ours against SB3: the ratio of the means with its interval, or, when either mean is ≤ 0,
    the difference of the means (``kind`` says which).

    Examples:
        >>> compare([110.0, 90.0], [100.0])["kind"], compare([10.0, -30.0], [100.0])["kind"]
        ('ratio', 'difference')
    """
    if np.mean(ours) > 0 and np.mean(theirs) > 0:
        return {"kind": "ratio", **bootstrap_interval((ours, theirs), ratio_of_means)._asdict()}
    return {"kind": "difference", **bootstrap_interval((ours, theirs), difference_of_means)._asdict()}


def _return_format(*values: float) -> str:
    """How returns print: whole numbers where any value is 10 or more in size, else as many
    decimals as show the largest one's first two digits (a return of about 0 would otherwise
    print as ``-0``).

    Examples:
        >>> f"{-0.0056:{_return_format(-0.0074, 0.0001)}}", f"{1234.5:{_return_format(1234.5, 3.0)}}"
        ('-0.0056', '1234')
    """
    largest = max(abs(v) for v in values)
    return ".0f" if largest >= 10 or largest == 0 else f".{1 - math.floor(math.log10(largest))}f"


def _interval_text(interval: dict[str, Any] | Interval, unit: str = "") -> str:
    data = interval if isinstance(interval, dict) else interval._asdict()
    ratio = data.get("kind") == "ratio" or unit == "×"
    digits = ".2f" if ratio else _return_format(data["estimate"], data["low"], data["high"])
    suffix, sign = ("×", "") if ratio else ("", "+")
    return (f"{data['estimate']:{sign}{digits}}{suffix} [{data['low']:{sign}{digits}}, "
            f"{data['high']:{sign}{digits}}]")


def _mean_sd(values: list[float]) -> str:
    mean = float(np.mean(values))
    spread = float(np.std(values, ddof=1)) if len(values) > 1 else 0.0
    digits = _return_format(mean, spread)
    return f"{mean:{digits}} ± {spread:{digits}}"


def statistics(runs: dict[tuple[str, str, str], dict[str, dict[int, dict]]]) -> dict[str, Any]:
    """The report's numbers (its JSON): per cell ``<algo>/<env>/<noise>`` the finals, speeds and
    comparisons; per ``<algo>/<env>`` SDE − Gaussian on each side and in the paper."""
    cells: dict[str, Any] = {}
    for (algorithm, env, noise), sides in runs.items():
        paper = PAPER.get((algorithm, env), {}).get(noise)
        entry: dict[str, Any] = {"paper": None if paper is None else list(paper)}
        for side in SIDES:
            seeds = sorted(sides[side])
            if seeds:
                finals = [sides[side][s]["final"] for s in seeds]
                entry[side] = {"seeds": seeds, "final": finals, "mean": float(np.mean(finals)),
                               "sd": float(np.std(finals, ddof=1)) if len(finals) > 1 else 0.0,
                               "speed": [sides[side][s]["speed"] for s in seeds],
                               "env_steps": sorted({sides[side][s]["env_steps"] for s in seeds})}
        if "ours" in entry and "sb3" in entry:
            entry["ours_vs_sb3"] = compare(entry["ours"]["final"], entry["sb3"]["final"])
            entry["speed_ratio"] = bootstrap_interval((entry["ours"]["speed"], entry["sb3"]["speed"]),
                                                      ratio_of_means)._asdict()
        cells[f"{algorithm}/{env}/{noise}"] = entry
    gains: dict[str, Any] = {}
    for algorithm, env in sorted({(a, e) for a, e, _ in runs}):
        paper = PAPER.get((algorithm, env))
        gain: dict[str, Any] = {"paper": None if paper is None else paper["sde"][0] - paper["gaussian"][0]}
        for side in SIDES:
            sde, gauss = (cells.get(f"{algorithm}/{env}/{n}", {}).get(side) for n in ("sde", "gaussian"))
            if sde and gauss:
                gain[side] = bootstrap_interval((sde["final"], gauss["final"]), difference_of_means)._asdict()
        gains[f"{algorithm}/{env}"] = gain
    return {"cells": cells, "sde_minus_gaussian": gains}


def page(manifest: dict[str, Any], stats: dict[str, Any]) -> str:
    """The markdown page of :func:`statistics`."""
    fraction, overrides = manifest["fraction"], manifest["overrides"]
    share = "all" if fraction == 1 else f"{fraction:g}"
    lines = [
        "# train.py's jobs against Stable-Baselines3, with the gSDE paper's numbers", "",
        "Generated by `python -m analysis.benchmarks.gsde_table report FOLDER` from the runs of "
        "`python -m analysis.benchmarks.gsde_table run --out FOLDER`.",
        f"Budget: {share} of each experiment's (rl-baselines3-zoo's n_timesteps, for the PyBullet envs the "
        "paper's; both sides, up to the first update past it); "
        f"overrides on both sides: {', '.join(f'`{o}`' for o in overrides) or 'none'}.",
        "Both sides run the settings of the cell's `train.py` experiment (`+experiment=<algo>_<env>_bullet`, or "
        "`sac_mountaincar`; `explorer=gaussian` for the Gaussian rows), the SB3 side's read off that config. "
        "Final return: the mean deterministic return of the last evaluation, mean ± sd over seeds. Ours ÷ SB3: "
        "ratio of the means, or ours − SB3 where a mean is ≤ 0; env steps/s: training and its evaluations. "
        "[95 % bootstrap intervals over seeds.] Paper: Raffin, Kober & Stulp (CoRL 2021), as SB3's docs print it "
        f"({', '.join(f'{a.upper()} {n} seeds' for a, n in PAPER_SEEDS.items())}, the full budget).", ""]
    for algorithm in ALGORITHMS:
        keys = [(env, noise) for env in ALL_ENVS for noise in NOISES if f"{algorithm}/{env}/{noise}" in stats["cells"]]
        if not keys:
            continue
        steps = {side: sorted({n for key in keys for n in stats["cells"][f"{algorithm}/{key[0]}/{key[1]}"]
                               .get(side, {}).get("env_steps", [])}) for side in SIDES}
        lines += [f"## {algorithm.upper()}", "",
                  "Env steps per run: " + "; ".join(f"{NAMES[side]} {', '.join(f'{n:,}' for n in steps[side]) or '–'}"
                                                    for side in SIDES) + ".", "",
                  "| env | noise | seeds (ours/SB3) | ours | SB3 | ours ÷ SB3 | paper | env steps/s ours ÷ SB3 |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for env, noise in keys:
            entry = stats["cells"][f"{algorithm}/{env}/{noise}"]
            seeds = "/".join(str(len(entry[s]["seeds"])) if s in entry else "0" for s in SIDES)
            sides = [_mean_sd(entry[s]["final"]) if s in entry else "–" for s in SIDES]
            versus = _interval_text(entry["ours_vs_sb3"]) if "ours_vs_sb3" in entry else "–"
            if entry.get("ours_vs_sb3", {}).get("kind") == "difference":
                versus = f"{versus} (difference)"
            speed = _interval_text(entry["speed_ratio"], "×") if "speed_ratio" in entry else "–"
            lines.append(f"| {ENV_IDS[env]} | {'SDE' if noise == 'sde' else 'Gaussian'} | {seeds} | {sides[0]} | "
                         f"{sides[1]} | {versus} | {paper_text(algorithm, env, noise)} | {speed} |")
        lines += ["", f"SDE − Gaussian, {algorithm.upper()}:", "",
                  "| env | ours | SB3 | paper |", "| --- | --- | --- | --- |"]
        for env in ALL_ENVS:
            gain = stats["sde_minus_gaussian"].get(f"{algorithm}/{env}")
            if gain is None:
                continue
            sides = [_interval_text(gain[s]) if s in gain else "–" for s in SIDES]
            paper = "–" if gain["paper"] is None else f"{gain['paper']:+d}"
            lines.append(f"| {ENV_IDS[env]} | {sides[0]} | {sides[1]} | {paper} |")
        lines.append("")
    return "\n".join(lines)


def plot(runs: dict[tuple[str, str, str], dict[str, dict[int, dict]]], env: str, path: Path) -> None:
    """One env's evaluation curves: a panel per algorithm, a line per noise and side (mean over
    seeds, band from the lowest to the highest seed)."""
    algorithms = [a for a in ALGORITHMS if any((a, env, n) in runs for n in NOISES)]
    with saved_figure(path, 1, len(algorithms), figsize=(5.5 * len(algorithms), 4), squeeze=False) as (_, axes):
        for ax, algorithm in zip(axes[0], algorithms, strict=True):
            for noise, color in zip(NOISES, ("C0", "C1"), strict=True):
                for side, linestyle in zip(SIDES, ("-", "--"), strict=True):
                    seeds = runs.get((algorithm, env, noise), {}).get(side, {})
                    if not seeds:
                        continue
                    curves = [np.asarray(run["evals"], dtype=float).reshape(-1, 2) for run in seeds.values()]
                    length = min(len(c) for c in curves)
                    values = np.stack([c[:length, 1] for c in curves])
                    x = curves[0][:length, 0]
                    label = (f"{NAMES[side]}, {'SDE' if noise == 'sde' else 'Gaussian'} "
                             f"({len(seeds)} seed{'s' if len(seeds) > 1 else ''})")
                    ax.plot(x, values.mean(0), color=color, linestyle=linestyle, marker=".", label=label)
                    if len(seeds) > 1:
                        ax.fill_between(x, values.min(0), values.max(0), color=color, alpha=0.12)
            ax.set_title(f"{algorithm.upper()}, {ENV_IDS[env]}", fontsize=9)
            ax.set_xlabel("env steps")
            ax.set_ylabel("deterministic evaluation return")
            ax.legend(fontsize=7)


def report(folder: Path, out: Path | None = None) -> str:
    """Write ``gsde_table.md``, ``gsde_table.json`` and ``gsde_table_<env>.png`` from ``folder``'s
    runs into ``out`` (default: ``folder``); returns the page."""
    out = folder if out is None else out
    manifest, runs = load(folder)
    stats = statistics(runs)
    text = page(manifest, stats)
    out.mkdir(parents=True, exist_ok=True)
    (out / "gsde_table.md").write_text(text)
    write_page_json(out / "gsde_table.json", {**manifest, **stats})
    for env in ALL_ENVS:
        if any(key[1] == env for key in runs):
            plot(runs, env, out / f"gsde_table_{env}.png")
    return text
