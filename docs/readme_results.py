"""The README's results summary, written from the result files the analysis scripts commit.

The README holds a short table of the headline results between the lines ``<!-- results:start -->``
and ``<!-- results:end -->``: one row per measure, one measure per cell (ours, the baseline's, the
paper's where it states one), and a short legend under it. This script writes that block from
``docs/table1/table1.json``, the ball-catching pages' JSON under ``docs/ballcatch/``
(``{fig5,fig6,methods,reevaluation}.json``, ``fig5_seed3/fig5.json``, ``fig6_selected/fig6.json``,
``methods_selected/methods.json``, ``selected/fig5.json``), the quick start's run
(``docs/ballcatch/runs/selected/seed0/summary.json``), ``docs/ppo/bench_ppo.json``,
``docs/sac/bench_sac.json`` and ``docs/sac/zoo_budget/bench_sac.json``, so that no figure in the
README is typed by hand::

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
NONE = "—"  # no such number (the paper's, or a baseline's)
LEGEND = (
    "A catch: a mean reward per step of at least −1.1 (a good catch: −1.0). *Reaching* a catch: some "
    "evaluation during training did; *ending* with one: the last evaluation did; *final policies catching "
    "on 20 episodes*: the final policy's mean over 20 fresh episodes did. Percentages are of runs, with "
    "their 95 % Wilson interval; ratios carry a 95 % bootstrap interval over seeds; ± is the standard "
    "deviation over seeds, their number in parentheses. —: no such number."
)


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
    """The README's results table (Markdown), one measure per cell, with its legend, from the committed result files."""
    table1 = _load("table1/table1.json")["rows"]
    ours = [row["speedup"] for row in table1]
    paper = [row["paper"]["speedup"] for row in table1]
    faster = sum(row["speedup_significant"] and row["speedup_ci"][0] > 1 for row in table1)
    fig5, fig6 = _load("ballcatch/fig5.json")["explorers"], _load("ballcatch/fig6.json")["explorers"]
    methods = _load("ballcatch/methods.json")["explorers"]
    selected = _load("ballcatch/selected/fig5.json")["explorers"]["sde"]
    fig5_selected = _load("ballcatch/fig5_seed3/fig5.json")["explorers"]
    fig6_selected = _load("ballcatch/fig6_selected/fig6.json")["explorers"]
    reevaluation = _load("ballcatch/reevaluation.json")["explorers"]
    held = {explorer: arms["pybrain_held"] for explorer, arms in reevaluation.items()}
    methods_selected = _load("ballcatch/methods_selected/methods.json")["explorers"]
    gpomdp_selected, pgpe_selected = methods_selected["sde+gpomdp"], methods_selected["pgpe"]
    quick_start = _load("ballcatch/runs/selected/seed0/summary.json")["final_eval_return"][0]
    ppo = _load("ppo/bench_ppo.json")
    sac = _load("sac/bench_sac.json")["mountaincar"]
    zoo = _load("sac/zoo_budget/bench_sac.json")["mountaincar"]
    ours_zoo, zoo_ratio = zoo["sde_compiled_policy"], zoo["sde_compiled_policy_over_sb3"]
    zoo_final = _interval(zoo_ratio["final"]) if "final" in zoo_ratio else \
        f"{zoo_ratio['final_difference']['estimate']:+.1f} [{zoo_ratio['final_difference']['low']:+.1f}, " \
        f"{zoo_ratio['final_difference']['high']:+.1f}] (difference)"

    def paper_percent(explorer: dict, level: str = CATCH) -> str:
        return f"{explorer['paper'][level]} %" if level in explorer.get("paper", {}) else NONE

    def mean_sd(values: list[float]) -> str:
        return f"{statistics.mean(values):.0f} ± {statistics.stdev(values):.0f} ({len(values)})"

    table1_page, fig_page = "docs/reproduce/table1.md", "docs/reproduce/fig5_6.md"
    methods_page, ppo_page, sac_page = "docs/reproduce/methods.md", "docs/reproduce/ppo.md", "docs/reproduce/sac.md"
    fig5_sel, fig6_sel = "Fig. 5, each explorer's selected learner", "Fig. 6, each explorer's selected learner"
    rows = [  # (result, page, measure, ours, baseline, paper: ours, paper: baseline)
        ("Table 1, toy task", table1_page, "episodes REX needs ÷ episodes SDE needs, lowest to highest of "
         f"{len(table1)} settings", f"{min(ours):.1f}× to {max(ours):.1f}×", NONE,
         f"{min(paper):.1f}× to {max(paper):.1f}×", NONE),
        ("Table 1, toy task", table1_page, "settings where SDE is significantly faster",
         f"{faster} of {len(table1)}", NONE, NONE, NONE),
        ("Fig. 5, REINFORCE, paper's settings", fig_page,
         f"runs reaching a catch ({fig5['sde']['runs']} each)", f"SDE {_percent(fig5['sde'])}",
         f"REX {_percent(fig5['rex'])}", paper_percent(fig5["sde"]), paper_percent(fig5["rex"])),
        ("Fig. 6, ENAC, paper's settings", fig_page, f"runs reaching a catch ({fig6['sde']['runs']} each)",
         f"SDE {_percent(fig6['sde'])}", f"REX {_percent(fig6['rex'])}", paper_percent(fig6["sde"]),
         paper_percent(fig6["rex"])),
    ]
    for name, counts in ((fig5_sel, fig5_selected), (fig6_sel, fig6_selected)):
        runs = counts["sde"]["runs"]
        rows += [
            (name, fig_page, f"runs ending with a catch ({runs} each)", f"SDE {_percent(counts['sde'], 'final')}",
             f"REX {_percent(counts['rex'], 'final')}", NONE, NONE),
            (name, fig_page, "final policies catching on 20 episodes", f"SDE {_percent(counts['sde'], 'final_policy')}",
             f"REX {_percent(counts['rex'], 'final_policy')}", NONE, NONE),
            (name, fig_page, "runs reaching a catch", f"SDE {_percent(counts['sde'])}",
             f"REX {_percent(counts['rex'])}", paper_percent(counts["sde"]), paper_percent(counts["rex"])),
        ]
    held_name = "Fig. 5, the earlier selected learners, arm held level (a diagnostic)"
    rows += [
        (held_name, fig_page, f"final policies catching on 20 episodes ({held['sde']['runs']} each)",
         f"SDE {_held(held['sde'], 'catches')}", f"REX {_held(held['rex'], 'catches')}",
         f"{paper_percent(fig5_selected['sde'])} reach one in training", NONE),
        (held_name, fig_page, "final policies making a good catch on 20 episodes",
         f"SDE {_held(held['sde'], 'good_catches')}", f"REX {_held(held['rex'], 'good_catches')}",
         f"{paper_percent(fig5_selected['sde'], '-1.0')} reach one in training", NONE),
    ]
    rows += [
        ("`+experiment=ballcatch`, seed 4242", fig_page, f"runs ending with a catch ({selected['runs']})",
         f"SDE {_percent(selected, 'final')}", NONE, NONE, NONE),
        ("`+experiment=ballcatch`, seed 4242", fig_page, "runs reaching a catch", f"SDE {_percent(selected)}", NONE,
         paper_percent(selected), NONE),
        ("`+experiment=ballcatch`, the quick start's seed 0", fig_page, "final evaluation (mean reward per step)",
         f"SDE {quick_start:.2f}", NONE, NONE, NONE),
        ("Fig. 5's paper settings, other methods", methods_page,
         f"runs reaching a catch ({methods['pgpe']['runs']} each)", f"PGPE {_percent(methods['pgpe'])}",
         f"SDE {_percent(methods['sde'])}", NONE, NONE),
        ("Fig. 5's paper settings, other methods", methods_page, "runs reaching a catch",
         f"GPOMDP + SDE {_percent(methods['sde+gpomdp'])}", f"SDE {_percent(methods['sde'])}", NONE, NONE),
    ]
    both = {pgpe_selected["runs"], gpomdp_selected["runs"]}
    each = f"{both.pop()} each" if len(both) == 1 else f"PGPE {pgpe_selected['runs']}, GPOMDP {gpomdp_selected['runs']}"
    for measure, which in ((f"runs ending with a catch ({each})", "final"),
                           ("final policies catching on 20 episodes", "final_policy"),
                           ("runs reaching a catch", "best")):
        rows.append(("Other methods at their selected learners", methods_page, measure,
                     f"PGPE {_percent(pgpe_selected, which)}", f"GPOMDP + SDE {_percent(gpomdp_selected, which)}",
                     NONE, NONE))
    rows += [
        ("PPO, HalfCheetahBullet", ppo_page, "final return, mean ± sd (seeds)", f"SDE {mean_sd(ppo['sde']['final'])}",
         f"SB3 gSDE {mean_sd(ppo['sb3']['final'])}", NONE, NONE),
        ("PPO, HalfCheetahBullet", ppo_page, "final return, ours ÷ SB3's", _interval(ppo["sde_over_sb3"]["final"]),
         NONE, NONE, NONE),
        (f"SAC, MountainCarContinuous, the zoo's {ours_zoo['steps']:,} steps", sac_page,
         "final deterministic return, mean ± sd (seeds)", f"SDE {mean_sd(ours_zoo['final'])}",
         f"SB3 gSDE {mean_sd(zoo['sb3']['final'])}", NONE, NONE),
        (f"SAC, MountainCarContinuous, the zoo's {ours_zoo['steps']:,} steps", sac_page,
         "final deterministic return, ours ÷ SB3's", zoo_final, NONE, NONE, NONE),
        (f"SAC, MountainCarContinuous, the zoo's {ours_zoo['steps']:,} steps", sac_page,
         "env steps per second, ours ÷ SB3's", _interval(zoo_ratio["speed"]), NONE, NONE, NONE),
        (f"SAC, MountainCarContinuous, {sac['sde']['steps']:,} steps", sac_page,
         "late training return, ours ÷ SB3's", _interval(sac["sde_over_sb3"]["late"]), NONE, NONE, NONE),
    ]
    lines = ["| result | measure | ours | baseline | paper: ours | paper: baseline |",
             "| --- | --- | --- | --- | --- | --- |"]
    lines += [f"| [{result}]({page}) | {measure} | {value} | {baseline} | {theirs} | {their_baseline} |"
              for result, page, measure, value, baseline, theirs, their_baseline in rows]
    return "\n".join(lines) + "\n\n" + LEGEND + "\n"


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
