"""The README's headline results and the results page, written from the result files the
analysis scripts commit.

The README holds a table of at most eight headline results, one per claim, between the lines
``<!-- results:start -->`` and ``<!-- results:end -->``; ``docs/reproduce/results.md`` holds every
result, between the same lines. Both tables have one measure per cell (each method's value and its
interval in their own columns, the paper's where it states one) and a one-line legend under them.
This script writes both blocks from ``docs/table1/table1.json``, the ball-catching pages' JSON under
``docs/study/ballcatch/`` (``{fig5,fig6,methods,reevaluation}.json``, ``fig5_seed3/fig5.json``,
``fig6_seed6/fig6.json``, ``checked/checked.json``, ``methods_selected/methods.json``,
``methods_seed4/methods.json``, ``selected/fig5.json``), the quick start's earlier run
(``results/ballcatch/runs/selected/seed0/summary.json``), ``docs/ppo/gsde_table.json``,
``docs/sac/gsde_table.json``, ``docs/gsde_table/gsde_table.json`` and the speed tables the
benchmarks' ``speed`` command writes (``docs/ppo/speed.md``, ``docs/sac/speed_job.md``), so that
no figure in either is typed by hand::

    python docs/readme_results.py           # rewrite both tables
    python docs/readme_results.py --check   # exit 1 if either is not what this writes

``tests/test_readme.py`` runs the check. Rerun an analysis script, then this one.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
RESULTS = DOCS.parent / "results"  # the committed run records
README = DOCS.parent / "README.md"
RESULTS_PAGE = DOCS / "reproduce" / "results.md"
#: The most rows the README's headline table may have.
HEADLINE_ROWS = 8
START, END = "<!-- results:start -->", "<!-- results:end -->"
CATCH = "-1.1"  # the paper's "catch" level: mean reward per step of at least -1.1
GOOD_CATCH = "-1.0"  # its "good catch" level
NONE = "—"  # no such number (the paper's, or a baseline's)
HEADER = ("result", "methods", "measure", "first", "95 % interval", "second", "95 % interval", "paper: first",
          "paper: second")
LEGEND = (
    "*methods*: the two compared, first vs second; *first*, *second*: our value for each (a ratio or count "
    "comparing the two is under *first*), its 95 % interval beside it (Wilson for a share of runs, bootstrap "
    "over seeds for a ratio, over timed processes for a speed); *paper*: the paper's value for the same "
    "measure; a catch: a mean reward per step of at least −1.1 (a good catch: −1.0); —: no such number."
)


def _load(path: str) -> dict:
    return json.loads((DOCS / path).read_text())


def _share(explorer: dict, which: str = "best", level: str = CATCH) -> tuple[str, str]:
    """A share of runs at ``level`` (a catch) and its Wilson interval: ``("24 %", "[14, 37]")``."""
    runs, count = explorer["runs"], explorer[which][level]
    low, high = explorer[f"{which}_interval"][level]
    return f"{round(100 * count / runs)} %", f"[{round(100 * low)}, {round(100 * high)}]"


def _held(arm: dict, key: str) -> tuple[str, str]:
    low, high = arm[f"{key}_interval"]
    return f"{round(100 * arm[key] / arm['runs'])} %", f"[{round(100 * low)}, {round(100 * high)}]"


def _ratio(ratio: dict) -> tuple[str, str]:
    """A ratio over seeds and its bootstrap interval: ``("0.97×", "[0.91, 1.05]")``."""
    return f"{ratio['estimate']:.2f}×", f"[{ratio['low']:.2f}, {ratio['high']:.2f}]"


def _speed_ratio(path: str, variant: str = "job") -> tuple[str, str]:
    """``variant``'s env steps per second ÷ SB3's and its interval, from a table written by a
    benchmark's ``speed`` command: ``("1.04×", "[1.02, 1.05]")``.

    Examples:
        >>> _speed_ratio("ppo/speed.md")[0].endswith("×")
        True
    """
    lines = [line for line in (DOCS / path).read_text().splitlines() if line.startswith("| ")]
    header = [cell.strip() for cell in lines[0].strip("|").split("|")]
    column = header.index("× SB3's env steps / s")
    for line in lines[2:]:
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        if cells[0] == variant:
            estimate, interval = cells[column].split(" ", 1)
            return f"{estimate}×", interval
    raise KeyError(f"{path} has no row for {variant!r}")


def _difference(difference: dict) -> tuple[str, str]:
    return f"{difference['estimate']:+.1f}", f"[{difference['low']:+.1f}, {difference['high']:+.1f}]"


def _mean_of(first: list[float], second: list[float]) -> str:
    seeds = {len(first), len(second)}
    return f"mean of {seeds.pop()} seeds each" if len(seeds) == 1 else f"mean of {len(first)} and {len(second)} seeds"


def summary() -> str:
    """The results page's table (Markdown), every result, one measure per cell, with its legend."""
    table1 = _load("table1/table1.json")["rows"]
    ours = [row["speedup"] for row in table1]
    paper = [row["paper"]["speedup"] for row in table1]
    faster = sum(row["speedup_significant"] and row["speedup_ci"][0] > 1 for row in table1)
    fig5, fig6 = _load("study/ballcatch/fig5.json")["explorers"], _load("study/ballcatch/fig6.json")["explorers"]
    methods = _load("study/ballcatch/methods.json")["explorers"]
    selected = _load("study/ballcatch/selected/fig5.json")["explorers"]["sde"]
    fig5_selected = _load("study/ballcatch/fig5_seed3/fig5.json")["explorers"]
    fig6_selected = _load("study/ballcatch/fig6_seed6/fig6.json")["explorers"]
    reevaluation = _load("study/ballcatch/reevaluation.json")["explorers"]
    held = {explorer: arms["pybrain_held"] for explorer, arms in reevaluation.items()}
    methods_selected = _load("study/ballcatch/methods_selected/methods.json")["explorers"]
    gpomdp_selected, pgpe_selected = methods_selected["sde+gpomdp"], methods_selected["pgpe"]
    methods_latest = _load("study/ballcatch/methods_seed4/methods.json")["explorers"]
    quick_start_run = RESULTS / "ballcatch" / "runs" / "selected" / "seed0" / "summary.json"
    quick_start = json.loads(quick_start_run.read_text())["final_eval_return"][0]
    ppo = _load("ppo/gsde_table.json")["cells"]["ppo/halfcheetah/sde"]
    sac = _load("sac/gsde_table.json")["cells"]["sac/mountaincar/sde"]

    def paper_share(explorer: dict, level: str = CATCH) -> str:
        return f"{explorer['paper'][level]} %" if level in explorer.get("paper", {}) else NONE

    def mean(values: list[float]) -> str:
        return f"{statistics.mean(values):.0f}"

    def catches(name: str, page: str, methods: str, counts: tuple[dict, dict], measure: str, which: str,
                paper: bool = False, level: str = CATCH) -> tuple:
        first, second = counts
        runs = {first["runs"], second["runs"]}
        each = f"{runs.pop()} each" if len(runs) == 1 else f"{first['runs']} and {second['runs']}"
        return (name, page, methods, f"{measure}, of {each}", *_share(first, which, level),
                *_share(second, which, level), paper_share(first, level) if paper else NONE,
                paper_share(second, level) if paper else NONE)

    table1_page, fig_page = "docs/reproduce/table1.md", "docs/reproduce/fig5_6.md"
    paper_page = "docs/study/chosen/ballcatch_paper_settings.md"
    diagnostics_page = "docs/study/chosen/ballcatch_diagnostics.md"
    method_page = "docs/study/chosen/ballcatch_method.md"
    methods_page, ppo_page, sac_page = "docs/reproduce/methods.md", "docs/reproduce/ppo.md", "docs/reproduce/sac.md"
    reaching, ending = "runs reaching a catch in training", "runs whose last evaluation is a catch"
    ending_good = "runs whose last evaluation is a good catch"
    on_20 = "final policies catching over 20 new balls"
    sde_rex, needs = "SDE vs REX", "episodes REX needs ÷ episodes SDE needs"
    rows = [  # (result, page, methods, measure, first, its interval, second, its interval, paper: first, paper: second)
        ("Table 1, toy task", table1_page, sde_rex, f"{needs}, lowest of {len(table1)} settings", f"{min(ours):.1f}×",
         NONE, NONE, NONE, f"{min(paper):.1f}×", NONE),
        ("Table 1, toy task", table1_page, sde_rex, f"{needs}, highest of {len(table1)} settings", f"{max(ours):.1f}×",
         NONE, NONE, NONE, f"{max(paper):.1f}×", NONE),
        ("Table 1, toy task", table1_page, sde_rex, "settings where SDE is significantly faster",
         f"{faster} of {len(table1)}", NONE, NONE, NONE, NONE, NONE),
        catches("Fig. 5, REINFORCE, paper's settings", paper_page, sde_rex, (fig5["sde"], fig5["rex"]), reaching,
                "best", paper=True),
        catches("Fig. 6, ENAC, paper's settings", paper_page, sde_rex, (fig6["sde"], fig6["rex"]), reaching, "best",
                paper=True),
        *_checked_rows(fig_page),
    ]
    for name, counts in (("Fig. 5, each explorer's selected learner", fig5_selected),
                         ("Fig. 6, each explorer's selected learner", fig6_selected)):
        pair = (counts["sde"], counts["rex"])
        rows += [catches(name, fig_page, sde_rex, pair, ending, "final"),
                 catches(name, fig_page, sde_rex, pair, ending_good, "final", level=GOOD_CATCH),
                 catches(name, fig_page, sde_rex, pair, on_20, "final_policy"),
                 catches(name, fig_page, sde_rex, pair, reaching, "best", paper=True)]
    held_name = "Fig. 5, the earlier selected learners, arm held level (a diagnostic)"
    held_runs = f"of {held['sde']['runs']} each" if held["sde"]["runs"] == held["rex"]["runs"] else \
        f"of {held['sde']['runs']} and {held['rex']['runs']}"
    rows += [
        (held_name, diagnostics_page, sde_rex, f"{on_20}, {held_runs}", *_held(held["sde"], "catches"),
         *_held(held["rex"], "catches"), NONE, NONE),
        (held_name, diagnostics_page, sde_rex, f"final policies making a good catch over 20 new balls, {held_runs}",
         *_held(held["sde"], "good_catches"), *_held(held["rex"], "good_catches"), NONE, NONE),
    ]
    seed_4242 = "`+experiment=ballcatch_reinforce`, seed 4242"
    rows += [
        (seed_4242, method_page, "SDE", f"{ending}, of {selected['runs']}", *_share(selected, "final"), NONE, NONE,
         NONE, NONE),
        (seed_4242, method_page, "SDE", f"{reaching}, of {selected['runs']}", *_share(selected), NONE, NONE,
         paper_share(selected), NONE),
        ("`+experiment=ballcatch_reinforce`, seed 0", method_page, "SDE",
         "final evaluation, mean reward per step", f"{quick_start:.2f}", NONE, NONE, NONE, NONE, NONE),
        catches("Fig. 5's paper settings, other methods", methods_page, "PGPE vs SDE",
                (methods["pgpe"], methods["sde"]), reaching, "best"),
        catches("Fig. 5's paper settings, other methods", methods_page, "GPOMDP + SDE vs SDE",
                (methods["sde+gpomdp"], methods["sde"]), reaching, "best"),
    ]
    for measure, which in ((ending, "final"), (on_20, "final_policy"), (reaching, "best")):
        rows.append(catches("Other methods at their earlier selected learners", methods_page, "PGPE vs GPOMDP + SDE",
                            (pgpe_selected, gpomdp_selected), measure, which))
    pgpe_latest = "PGPE and REINFORCE + SDE, each at its latest learner"
    for measure, which in ((ending, "final"), (ending_good, "final")):
        rows.append(catches(pgpe_latest, methods_page, "PGPE vs SDE", (methods_latest["pgpe"], methods_latest["sde"]),
                            measure, which, level=GOOD_CATCH if measure == ending_good else CATCH))
    rows += _versus_sb3_rows(f"PPO, HalfCheetahBullet, {ppo['ours']['env_steps'][0]:,} steps", ppo_page, ppo,
                             "final return")
    rows += _versus_sb3_rows(f"SAC, MountainCarContinuous, the zoo's {sac['ours']['env_steps'][0]:,} steps", sac_page,
                             sac, "final deterministic return")
    rows += [
        ("`+experiment=ppo_halfcheetah_bullet`", ppo_page, "SDE vs SB3 gSDE",
         "env steps per second of one iteration, first ÷ second", *_speed_ratio("ppo/speed.md"), NONE, NONE, NONE,
         NONE),
        ("`+experiment=sac_mountaincar`", sac_page, "SDE vs SB3 gSDE",
         "env steps per second of one round, first ÷ second", *_speed_ratio("sac/speed_job.md"), NONE, NONE, NONE,
         NONE),
    ]
    rows += _gsde_rows(_load("gsde_table/gsde_table.json"), "docs/reproduce/gsde_table.md")
    return _table([(result, _from_reproduce(page), *cells) for result, page, *cells in rows])


def _from_reproduce(page: str) -> str:
    """A page's link from ``docs/reproduce/`` (the results page's folder).

    Examples:
        >>> _from_reproduce("docs/reproduce/table1.md"), _from_reproduce("docs/study/chosen/ballcatch_method.md")
        ('table1.md', '../study/chosen/ballcatch_method.md')
    """
    return page.removeprefix("docs/reproduce/") if page.startswith("docs/reproduce/") else f"../{page[5:]}"





def headline() -> str:
    """The README's table: one row per headline claim, at most :data:`HEADLINE_ROWS`."""
    table1 = _load("table1/table1.json")["rows"]
    ours = [row["speedup"] for row in table1]
    paper = [row["paper"]["speedup"] for row in table1]
    fig5_selected = _load("study/ballcatch/fig5_seed3/fig5.json")["explorers"]
    ppo = _load("ppo/gsde_table.json")["cells"]["ppo/halfcheetah/sde"]
    sac = _load("sac/gsde_table.json")["cells"]["sac/mountaincar/sde"]
    fig_page = "docs/reproduce/fig5_6.md"
    first, second = fig5_selected["sde"], fig5_selected["rex"]
    paper_fig5 = f"{first['paper'][CATCH]} %" if CATCH in first.get("paper", {}) else NONE
    rows = [
        ("Table 1, toy task", "docs/reproduce/table1.md", "lowest vs highest of its settings",
         f"episodes REX needs ÷ episodes SDE needs, {len(table1)} settings", f"{min(ours):.1f}×", NONE,
         f"{max(ours):.1f}×", NONE, f"{min(paper):.1f}×", f"{max(paper):.1f}×"),
        ("Fig. 5, ball catching, REINFORCE", fig_page, "SDE vs REX",
         f"runs reaching a catch in training, of {first['runs']} each", *_share(first, "best"),
         *_share(second, "best"), paper_fig5, NONE),
        *_checked_rows(fig_page),
        _versus_sb3_rows(f"PPO, HalfCheetahBullet, {ppo['ours']['env_steps'][0]:,} steps", "docs/reproduce/ppo.md",
                         ppo, "final return")[1],
        _versus_sb3_rows(f"SAC, MountainCarContinuous, {sac['ours']['env_steps'][0]:,} steps", "docs/reproduce/sac.md",
                         sac, "final deterministic return")[1],
        _gsde_rows(_load("gsde_table/gsde_table.json"), "docs/reproduce/gsde_table.md")[1],
    ]
    if len(rows) > HEADLINE_ROWS:
        raise ValueError(f"the README's headline table has {len(rows)} rows, at most {HEADLINE_ROWS}")
    return _table(rows)


def _checked_rows(page: str) -> list[tuple]:
    """The headline learner (Fig. 6's setting, best policies kept), SDE against REX with the same
    learner: runs reaching a catch in training (beside the paper's Fig. 6 counts), best and final
    policies catching on the fresh balls."""
    checked = _load("study/ballcatch/checked/checked.json")["explorers"]
    sde, rex = checked["sde"], checked["rex"]
    fig6 = _load("study/ballcatch/fig6.json")["explorers"]
    paper = {name: f"{fig6[name]['paper'][CATCH]} %" for name in ("sde", "rex") if CATCH in fig6[name].get("paper", {})}

    def share(explorer: dict, key: str) -> tuple[str, str]:
        count, (low, high) = explorer["counts"]["catch"][key], explorer["intervals"]["catch"][key]
        return f"{round(100 * count / explorer['runs'])} %", f"[{round(100 * low)}, {round(100 * high)}]"

    runs = f"of {sde['runs']} each" if sde["runs"] == rex["runs"] else f"of {sde['runs']} and {rex['runs']}"
    name = "Fig. 6, ball catching, ENAC (`+experiment=ballcatch`), best policies kept"
    return [
        (name, page, "SDE vs REX", f"runs reaching a catch in training, {runs}", *share(sde, "reached"),
         *share(rex, "reached"), paper.get("sde", NONE), paper.get("rex", NONE)),
        (name, page, "SDE vs REX", f"best policies catching on {sde['episodes']} fresh balls, {runs}",
         *share(sde, "best_checked"), *share(rex, "best_checked"), NONE, NONE),
        (name, page, "SDE vs REX", f"final policies catching on {sde['episodes']} fresh balls, {runs}",
         *share(sde, "final_checked"), *share(rex, "final_checked"), NONE, NONE),
    ]


def _table(rows: list[tuple]) -> str:
    lines = ["| " + " | ".join(HEADER) + " |", "| " + " | ".join("---" for _ in HEADER) + " |"]
    lines += [f"| [{result}]({page}) | " + " | ".join(cells) + " |" for result, page, *cells in rows]
    return "\n".join(lines) + "\n\n" + LEGEND + "\n"


def _versus_sb3_rows(name: str, page: str, cell: dict, measure: str) -> list[tuple[str, ...]]:
    """A cell of a ``gsde_table`` report, ours against SB3: both sides' mean final return, ours ÷
    SB3's (or ours − SB3's where a return is not positive) and the ratio of env steps per second.

    Examples:
        >>> side = {"final": [90.0, 94.0], "speed": [1.0, 1.0]}
        >>> cell = {"ours": side, "sb3": side, "ours_vs_sb3": {"kind": "difference", "estimate": 0.0, "low": -2.0,
        ...         "high": 2.0}, "speed_ratio": {"estimate": 1.0, "low": 0.9, "high": 1.1}}
        >>> [row[3:6] for row in _versus_sb3_rows("SAC", "p.md", cell, "final return")]
        [('final return, mean of 2 seeds each', '92', '—'), ('final return, first − second', '+0.0', '[-2.0, +2.0]'), \
('env steps per second, first ÷ second', '1.00×', '[0.90, 1.10]')]
    """
    methods, versus = "SDE vs SB3 gSDE", cell["ours_vs_sb3"]
    final = ("first ÷ second", *_ratio(versus)) if versus["kind"] == "ratio" else \
        ("first − second", *_difference(versus))
    seeds = _mean_of(cell["ours"]["final"], cell["sb3"]["final"])
    return [
        (name, page, methods, f"{measure}, {seeds}", f"{statistics.mean(cell['ours']['final']):.0f}", NONE,
         f"{statistics.mean(cell['sb3']['final']):.0f}", NONE, NONE, NONE),
        (name, page, methods, f"{measure}, {final[0]}", *final[1:], NONE, NONE, NONE, NONE),
        (name, page, methods, "env steps per second, first ÷ second", *_ratio(cell["speed_ratio"]), NONE, NONE, NONE,
         NONE),
    ]


def _gsde_rows(table: dict, page: str) -> list[tuple[str, ...]]:
    """The gSDE table's rows: in how many cells (algorithm, env, noise) ours and SB3's final
    returns do not differ significantly (the interval of ours ÷ SB3, or ours − SB3, holds parity),
    and ours ÷ SB3's env steps per second over the cells.

    Examples:
        >>> cell = {"ours_vs_sb3": {"kind": "ratio", "low": 0.8, "high": 1.2}, "speed_ratio": {"estimate": 0.9}}
        >>> other = {"ours_vs_sb3": {"kind": "difference", "low": 5.0, "high": 9.0}, "speed_ratio": {"estimate": 1.1}}
        >>> rows = _gsde_rows({"fraction": 0.02, "cells": {"ppo/hopper/sde": cell, "a2c/ant/sde": other}}, "p.md")
        >>> rows[0][3:5]
        ('final return: cells where ours and SB3 do not differ significantly', '1 of 2')
        >>> rows[1][3:5]
        ('env steps per second, first ÷ second: median of the 2 cells (lowest 0.90×, highest 1.10×)', '1.00×')
    """
    compared = {key: cell for key, cell in table["cells"].items() if "ours_vs_sb3" in cell}
    parity = {"ratio": 1.0, "difference": 0.0}
    alike = sum(cell["ours_vs_sb3"]["low"] <= parity[cell["ours_vs_sb3"]["kind"]] <= cell["ours_vs_sb3"]["high"]
                for cell in compared.values())
    speeds = sorted(cell["speed_ratio"]["estimate"] for cell in compared.values())
    algorithms = sorted({key.split("/")[0].upper() for key in compared})
    name = f"gSDE paper's PyBullet table ({', '.join(algorithms)}), {table['fraction']:g} of its budget"
    return [
        (name, page, "ours vs SB3", "final return: cells where ours and SB3 do not differ significantly",
         f"{alike} of {len(compared)}", NONE, NONE, NONE, NONE, NONE),
        (name, page, "ours vs SB3", f"env steps per second, first ÷ second: median of the {len(speeds)} cells "
         f"(lowest {speeds[0]:.2f}×, highest {speeds[-1]:.2f}×)", f"{statistics.median(speeds):.2f}×", NONE, NONE,
         NONE, NONE, NONE),
    ]


def replaced(text: str, table: str | None = None) -> str:
    """``text`` (the README, or the results page) with its results block set to ``table``
    (default: the README's :func:`headline`)."""
    head, sep, rest = text.partition(START)
    _, sep2, tail = rest.partition(END)
    if not sep or not sep2:
        raise ValueError(f"the page lacks the lines {START} and {END}")
    return f"{head}{START}\n{headline() if table is None else table}{END}{tail}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if either table differs, write nothing")
    args = parser.parse_args(argv)
    stale = []
    for path, table in ((README, headline()), (RESULTS_PAGE, summary())):
        text = path.read_text()
        new = replaced(text, table)
        if new == text:
            continue
        if args.check:
            stale.append(path.name)
        else:
            path.write_text(new)
    if stale:
        print(f"{', '.join(stale)}: the results table is not what docs/readme_results.py writes: run it",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
