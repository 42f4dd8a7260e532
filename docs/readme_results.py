"""The README's results summary, written from the result files the analysis scripts commit.

The README holds a short table of the headline results between the lines ``<!-- results:start -->``
and ``<!-- results:end -->``. This script writes that table from ``docs/table1/table1.json``,
the ball-catching pages' JSON under ``docs/ballcatch/`` (``{fig5,fig6,methods,reevaluation}.json``,
``fig5_selected/fig5.json``, ``fig6_selected/fig6.json``, ``methods_selected/methods.json``,
``selected/fig5.json``), the quick start's run (``docs/ballcatch/runs/selected/seed0/summary.json``),
``docs/ppo/bench_ppo.json`` and ``docs/sac/bench_sac.json``, so that no figure in the README is typed by hand::

    python docs/readme_results.py           # rewrite the README's table
    python docs/readme_results.py --check   # exit 1 if the README's table is not what this writes

``tests/test_readme.py`` runs the check. Rerun an analysis script, then this one.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
README = DOCS.parent / "README.md"
START, END = "<!-- results:start -->", "<!-- results:end -->"
CATCH = "-1.1"  # the paper's "catch" level: mean reward per step of at least -1.1
PAGES = {"docs/reproduce/table1.md": "Table 1", "docs/reproduce/fig5_6.md": "Fig. 5 and 6",
         "docs/reproduce/methods.md": "methods", "docs/reproduce/ppo.md": "PPO",
         "docs/reproduce/sac.md": "SAC"}


def _load(path: str) -> dict:
    return json.loads((DOCS / path).read_text())


def _percent(explorer: dict, which: str = "best") -> str:
    runs, count = explorer["runs"], explorer[which][CATCH]
    low, high = explorer[f"{which}_interval"][CATCH]
    return f"{round(100 * count / runs)} % [{round(100 * low)}, {round(100 * high)}]"


def _held(arm: dict, key: str) -> str:
    low, high = arm[f"{key}_interval"]
    return f"{round(100 * arm[key] / arm['runs'])} % [{round(100 * low)}, {round(100 * high)}]"


def summary() -> str:
    """The README's results table (Markdown), from the committed result files."""
    table1 = _load("table1/table1.json")["rows"]
    ours = [row["speedup"] for row in table1]
    paper = [row["paper"]["speedup"] for row in table1]
    faster = sum(row["speedup_significant"] and row["speedup_ci"][0] > 1 for row in table1)
    fig5, fig6 = _load("ballcatch/fig5.json")["explorers"], _load("ballcatch/fig6.json")["explorers"]
    methods = _load("ballcatch/methods.json")["explorers"]
    selected = _load("ballcatch/selected/fig5.json")["explorers"]["sde"]
    fig5_selected = _load("ballcatch/fig5_selected/fig5.json")["explorers"]
    fig6_selected = _load("ballcatch/fig6_selected/fig6.json")["explorers"]
    reevaluation = _load("ballcatch/reevaluation.json")["explorers"]
    held = {explorer: arms["pybrain_held"] for explorer, arms in reevaluation.items()}
    methods_selected = _load("ballcatch/methods_selected/methods.json")["explorers"]
    gpomdp_selected, pgpe_selected = methods_selected["sde+gpomdp"], methods_selected["pgpe"]
    quick_start = _load("ballcatch/runs/selected/seed0/summary.json")["final_eval_return"][0]
    ppo = _load("ppo/bench_ppo.json")
    ratio = ppo["sde_over_sb3"]
    sac = _load("sac/bench_sac.json")["mountaincar"]
    sac_ratio, sac_compiled = sac["sde_over_sb3"], sac["sde_compiled_over_sb3"]
    zoo = _load("sac/zoo_budget/bench_sac.json")["mountaincar"]
    ours_zoo, zoo_ratio = zoo["sde_compiled_policy"], zoo["sde_compiled_policy_over_sb3"]
    zoo_final = _interval(zoo_ratio["final"]) if "final" in zoo_ratio else \
        f"difference {zoo_ratio['final_difference']['estimate']:+.1f} [{zoo_ratio['final_difference']['low']:+.1f}, " \
        f"{zoo_ratio['final_difference']['high']:+.1f}]"

    def ends_keeps_reaches(counts: dict) -> str:
        return f"{_percent(counts, 'final')}; {_percent(counts, 'final_policy')}; {_percent(counts)}"

    def mean_sd(values: list[float]) -> str:
        return f"{statistics.mean(values):.0f} ± {statistics.stdev(values):.0f}"

    rows = [
        ("Table 1: episodes REX needs / SDE needs, 8 settings of the toy task",
         f"{min(ours):.1f}× to {max(ours):.1f}×, SDE significantly faster in {faster} of {len(table1)}",
         f"{min(paper):.1f}× to {max(paper):.1f}×", "docs/reproduce/table1.md"),
        (f"Fig. 5 (REINFORCE, paper's setting): runs reaching a catch, {fig5['sde']['runs']} runs each",
         f"SDE {_percent(fig5['sde'])}, REX {_percent(fig5['rex'])}",
         f"SDE {fig5['sde']['paper'][CATCH]} %", "docs/reproduce/fig5_6.md"),
        (f"Fig. 6 (ENAC): runs reaching a catch, {fig6['sde']['runs']} runs each",
         f"SDE {_percent(fig6['sde'])}, REX {_percent(fig6['rex'])}",
         f"SDE {fig6['sde']['paper'][CATCH]} %, REX {fig6['rex']['paper'][CATCH]} %", "docs/reproduce/fig5_6.md"),
        (f"Fig. 5 at each explorer's selected learner (REINFORCE), {fig5_selected['sde']['runs']} runs each: "
         "ending with a catch; the final policy catching on 20 episodes; reaching a catch",
         f"SDE {_percent(fig5_selected['sde'], 'final')}, REX {_percent(fig5_selected['rex'], 'final')}; "
         f"SDE {_percent(fig5_selected['sde'], 'final_policy')}, REX {_percent(fig5_selected['rex'], 'final_policy')}; "
         f"SDE {_percent(fig5_selected['sde'])}, REX {_percent(fig5_selected['rex'])}",
         f"SDE {fig5_selected['sde']['paper'][CATCH]} % reach one", "docs/reproduce/fig5_6.md"),
        (f"Fig. 5's final policies at the selected learners with the arm held level (a diagnostic, 20 episodes "
         f"each, {held['sde']['runs']} runs each): catching; making a good catch",
         f"SDE {_held(held['sde'], 'catches')}, REX {_held(held['rex'], 'catches')}; "
         f"SDE {_held(held['sde'], 'good_catches')}, REX {_held(held['rex'], 'good_catches')}",
         f"SDE {fig5_selected['sde']['paper'][CATCH]} % reach a catch, "
         f"{fig5_selected['sde']['paper']['-1.0']} % a good one (in training)", "docs/reproduce/fig5_6.md"),
        (f"Fig. 6 at each explorer's selected learner (ENAC, σ̂ fixed), {fig6_selected['sde']['runs']} runs each: "
         "ending with a catch; the final policy catching on 20 episodes; reaching a catch",
         f"SDE {_percent(fig6_selected['sde'], 'final')}, REX {_percent(fig6_selected['rex'], 'final')}; "
         f"SDE {_percent(fig6_selected['sde'], 'final_policy')}, REX {_percent(fig6_selected['rex'], 'final_policy')}; "
         f"SDE {_percent(fig6_selected['sde'])}, REX {_percent(fig6_selected['rex'])}",
         f"SDE {fig6_selected['sde']['paper'][CATCH]} %, REX {fig6_selected['rex']['paper'][CATCH]} % reach one",
         "docs/reproduce/fig5_6.md"),
        (f"`+experiment=ballcatch` (selected learner), {selected['runs']} runs (seed 4242): ending with a catch; "
         "the quick start's seed 0",
         f"{selected['final'][CATCH]} of {selected['runs']} ({_percent(selected, 'final')}); "
         f"{selected['best'][CATCH]} reach one; seed 0 ends at {quick_start:.2f} per step",
         f"{selected['paper'][CATCH]} % reach one",
         "docs/reproduce/fig5_6.md"),
        (f"GPOMDP + SDE and PGPE at their selected learners, {gpomdp_selected['runs']} and {pgpe_selected['runs']} "
         "runs: ending with a catch; the final policy catching on 20 episodes; reaching a catch",
         f"GPOMDP + SDE {ends_keeps_reaches(gpomdp_selected)} — PGPE {ends_keeps_reaches(pgpe_selected)}",
         "(not in the paper)", "docs/reproduce/methods.md"),
        (f"PGPE on Fig. 5's setting, {methods['pgpe']['runs']} runs: reaching a catch",
         f"PGPE {_percent(methods['pgpe'])}, SDE + GPOMDP {_percent(methods['sde+gpomdp'])}", "(not in the paper)",
         "docs/reproduce/methods.md"),
        ("PPO on HalfCheetahBullet, final return (seeds)",
         f"SDE {mean_sd(ppo['sde']['final'])} ({len(ppo['sde']['final'])}), SB3 gSDE "
         f"{mean_sd(ppo['sb3']['final'])} ({len(ppo['sb3']['final'])}): "
         f"{ratio['final']['estimate']:.2f}× [{ratio['final']['low']:.2f}, {ratio['final']['high']:.2f}]",
         "(not in the paper)", "docs/reproduce/ppo.md"),
        (f"SAC on MountainCarContinuous, {sac['sde']['steps']:,} steps: late training return (seeds); env steps/s",
         f"SDE {statistics.mean(sac['sde']['late']):.0f} ({len(sac['sde']['late'])}), SB3 gSDE "
         f"{statistics.mean(sac['sb3']['late']):.0f} ({len(sac['sb3']['late'])}): "
         f"{sac_ratio['late']['estimate']:.2f}× [{sac_ratio['late']['low']:.2f}, {sac_ratio['late']['high']:.2f}]; "
         f"speed {_interval(sac_ratio['speed'])}; compiled update: {_interval(sac_compiled['speed'])}, "
         f"{_interval(sac_compiled['speed_without_compilation'])} without the compilation",
         "(not in the paper)", "docs/reproduce/sac.md"),
        (f"SAC on MountainCarContinuous at the zoo's budget ({ours_zoo['steps']:,} steps), compiled update and policy "
         "forward: final deterministic return (seeds); env steps/s; per CPU second",
         f"SDE {mean_sd(ours_zoo['final'])} ({len(ours_zoo['final'])}), SB3 gSDE {mean_sd(zoo['sb3']['final'])} "
         f"({len(zoo['sb3']['final'])}): {zoo_final}; speed {_interval(zoo_ratio['speed'])}; "
         f"{_interval(zoo_ratio['cpu_speed'])}",
         "(not in the paper)", "docs/reproduce/sac.md"),
    ]
    lines = ["| result | ours [95 % interval] | paper | page |", "| --- | --- | --- | --- |"]
    lines += [f"| {what} | {value} | {theirs} | [{PAGES[page]}]({page}) |" for what, value, theirs, page in rows]
    return "\n".join(lines) + "\n"


def _interval(ratio: dict) -> str:
    return f"{ratio['estimate']:.2f}× [{ratio['low']:.2f}, {ratio['high']:.2f}]"


def replaced(text: str) -> str:
    """``text`` (the README) with its results block rewritten."""
    head, sep, rest = text.partition(START)
    _, sep2, tail = rest.partition(END)
    if not sep or not sep2:
        raise ValueError(f"README.md lacks the lines {START} and {END}")
    return f"{head}{START}\n{summary()}{END}{tail}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the README differs, write nothing")
    args = parser.parse_args(argv)
    text = README.read_text()
    new = replaced(text)
    if args.check:
        if new != text:
            print("README.md's results table is not what docs/readme_results.py writes: run it", file=sys.stderr)
            return 1
        return 0
    README.write_text(new)
    return 0


if __name__ == "__main__":
    sys.exit(main())
