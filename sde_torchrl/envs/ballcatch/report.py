"""Ball catching's report on a finished job (:class:`~sde_torchrl.envs.outcomes.OutcomeReport`):
in the paper's mean reward per step, the level each run reached (section 4.2,
:func:`~sde_torchrl.envs.ballcatch.outcomes.catch_level`), when, and what its best and final
policies did on the final check's fresh balls. Its schema
(:class:`~sde_torchrl.config.schemas.envs.BallCatchEnvConf`) declares it.
"""

from __future__ import annotations

from typing import Any

from sde_torchrl.envs.ballcatch.outcomes import BEHAVIOURS, LEVEL_NAMES, LEVELS, catch_level
from sde_torchrl.envs.outcomes import OutcomeReport

#: The levels that count as catching the ball (section 4.2: R >= -1.1).
CATCHES = ("good catch", "catch")


class CatchReport(OutcomeReport):
    """Levels, closing lines and comparison counts of a ball-catching job.

    Examples:
        >>> CatchReport().entries({"final_eval_return": [-1.05, -2.5]}, 1.0, None, None)
        {'final_eval_mean_reward': [-1.05, -2.5], 'final_eval_level': ['catch', 'dropped']}
        >>> lines = CatchReport().lines({"final_eval_return": [-1.05, -2.5]}, 1.0)
        >>> lines[0]
        'final evaluation per run (mean reward per step, no exploration): run 0 -1.050 catch, run 1 -2.500 dropped'
        >>> lines[1]
        'levels of the final evaluations: 0 good catch, 1 catch, 0 on the hand, 0 slowed, 1 dropped (of 2 runs)'
    """

    def entries(self, summary: dict[str, Any], scale: float, evaluations: dict[int, list[float]] | None,
                outcomes: dict[str, Any] | None) -> dict[str, Any]:
        """Per run: the final evaluation and its level; each level's first update among the periodic
        evaluations (``null``: never reached); with a final check, the level of the final and the
        best policies over the fresh episodes and how many of those episodes each policy dropped,
        kept on the hand or held (:func:`~sde_torchrl.envs.ballcatch.outcomes.catch_outcomes`)."""
        evals = [scale * value for value in summary["final_eval_return"]]
        out: dict[str, Any] = {"final_eval_mean_reward": evals,
                               "final_eval_level": [catch_level(value) for value in evals]}
        if evaluations:
            updates = sorted(evaluations)
            history = [[scale * value for value in evaluations[k]] for k in updates]  # [evaluations][runs]
            out["level_first_update"] = [
                {name: next((updates[i] for i in range(len(updates)) if history[i][r] >= bound), None)
                 for bound, name in LEVELS} for r in range(len(history[0]))]
        for name in ("final", "best"):
            if f"{name}_check_return" in summary:
                values = [scale * value for value in summary[f"{name}_check_return"]]
                out[f"{name}_check_mean_reward"] = values
                out[f"{name}_check_level"] = [catch_level(value) for value in values]
            reported = (outcomes or {}).get(name)
            if reported is not None:
                out[f"{name}_check_behaviours"] = [{label: codes.count(i) for i, label in enumerate(BEHAVIOURS)}
                                                   for codes in reported["behaviour"]]
        return out

    def lines(self, summary: dict[str, Any], scale: float) -> list[str]:
        """Per run, the final evaluation and its level, then one line of counts; with a final
        check, :meth:`checked_lines` instead."""
        if "best_check_return" in summary:
            return self.checked_lines(summary, scale)
        evals = [scale * value for value in summary["final_eval_return"]]
        levels = [catch_level(value) for value in evals]
        first = summary.get("first_run", 0)
        runs = ", ".join(f"run {first + i} {value:.3f} {level}"
                         for i, (value, level) in enumerate(zip(evals, levels, strict=True)))
        counts = ", ".join(f"{levels.count(name)} {name}" for name in LEVEL_NAMES)
        return [f"final evaluation per run (mean reward per step, no exploration): {runs}",
                f"levels of the final evaluations: {counts} (of {len(evals)} run{'s' if len(evals) > 1 else ''})"]

    def checked_lines(self, summary: dict[str, Any], scale: float) -> list[str]:
        """Per run, the best level its evaluations reached and when, and what its best and final
        policies did on the final check's fresh balls; then the counts.

        Examples:
            >>> summary = {"first_run": 0, "final_eval_return": [-1.5], "best_eval_return": [-0.94],
            ...            "best_update": [379], "check_episodes": 20, "best_check_return": [-1.02],
            ...            "final_check_return": [-1.49], "level_first_update": [{"good catch": 379, "catch": 259}],
            ...            "best_check_behaviours": [{"dropped": 2, "kept on the hand": 0, "held": 18}]}
            >>> for line in CatchReport().checked_lines(summary, 1.0):  # doctest: +NORMALIZE_WHITESPACE
            ...     print(line)
            run 0: reached a good catch at update 379 (a catch at 259); best policy (update 379, evaluated
            -0.940) on 20 fresh balls: -1.020, a catch (18 held, 0 kept on the hand, 2 dropped); final policy:
            -1.490, on the hand
            of 1 run, on 20 fresh balls each: the best policy catches in 1, the final policy in 0; a catch was
            reached in training by 1
        """
        first, episodes = summary.get("first_run", 0), summary["check_episodes"]
        lines = []
        reached_catch = 0
        for r, (best, final) in enumerate(zip(summary["best_check_return"], summary["final_check_return"],
                                              strict=True)):
            firsts = (summary.get("level_first_update") or [{}] * (r + 1))[r]
            top = next((name for name in LEVEL_NAMES if firsts.get(name) is not None), None)
            reached_catch += any(firsts.get(name) is not None for name in CATCHES)
            if top is None:
                reached = "reached none of the paper's levels"
            else:
                reached = f"reached {_a(top)} at update {firsts[top]}"
                if top == "good catch" and firsts.get("catch") not in (None, firsts[top]):
                    reached += f" (a catch at {firsts['catch']})"
            behaviours = (summary.get("best_check_behaviours") or [None] * (r + 1))[r]
            held = ("" if behaviours is None else
                    f" ({behaviours['held']} held, {behaviours['kept on the hand']} kept on the hand, "
                    f"{behaviours['dropped']} dropped)")
            best_value, final_value = scale * best, scale * final
            lines.append(
                f"run {first + r}: {reached}; best policy (update {summary['best_update'][r]}, evaluated "
                f"{scale * summary['best_eval_return'][r]:.3f}) on {episodes} fresh balls: {best_value:.3f}, "
                f"{_a(catch_level(best_value))}{held}; final policy: {final_value:.3f}, "
                f"{_a(catch_level(final_value))}")
        runs = len(summary["best_check_return"])
        catches = {name: sum(catch_level(scale * value) in CATCHES for value in summary[f"{name}_check_return"])
                   for name in ("best", "final")}
        lines.append(f"of {runs} run{'s' if runs > 1 else ''}, on {episodes} fresh balls each: the best policy "
                     f"catches in {catches['best']}, the final policy in {catches['final']}; a catch was reached in "
                     f"training by {reached_catch}")
        return lines

    def shares(self, summary: dict[str, Any]) -> dict[str, list[bool]]:
        """Per run: its last evaluation is a catch; its best policy catches on the fresh balls.

        Examples:
            >>> CatchReport().shares({"final_eval_level": ["catch", "slowed"]})
            {'last evaluation a catch': [True, False]}
        """
        counted = (("final_eval_level", "last evaluation a catch"),
                   ("best_check_level", "best policy catches on the fresh balls"))
        return {what: [level in CATCHES for level in summary[key]] for key, what in counted if key in summary}


def _a(level: str) -> str:
    """A level's name as the lines say it: "a catch", "on the hand", "dropped"."""
    return f"a {level}" if level in CATCHES else level
