"""The gSDE paper's PyBullet table (Raffin, Kober & Stulp, "Smooth Exploration for Robotic
Reinforcement Learning", CoRL 2021): final return, mean ± sd over seeds, Gaussian noise and gSDE,
as Stable-Baselines3's documentation prints it beside the zoo's hyperparameters.

Examples:
    >>> PAPER[("ppo", "hopper")]["gaussian"], PAPER[("ppo", "hopper")]["sde"]
    ((1567, 339), (2512, 21))
"""

from __future__ import annotations

#: (algorithm, env) → noise → (mean, sd) of the final return.
PAPER: dict[tuple[str, str], dict[str, tuple[int, int]]] = {
    # A2C and PPO: DLR-RM/stable-baselines3, docs/modules/a2c.rst (the same table in
    # docs/modules/ppo.rst), "Results", "PyBullet Environments": 2M steps, 6 seeds, "Gaussian" and
    # "gSDE" columns per algorithm.
    ("a2c", "halfcheetah"): {"gaussian": (2003, 54), "sde": (2032, 122)},
    ("a2c", "ant"): {"gaussian": (2286, 72), "sde": (2443, 89)},
    ("a2c", "hopper"): {"gaussian": (1627, 158), "sde": (1561, 220)},
    ("a2c", "walker2d"): {"gaussian": (577, 65), "sde": (839, 56)},
    ("ppo", "halfcheetah"): {"gaussian": (1976, 479), "sde": (2826, 45)},
    ("ppo", "ant"): {"gaussian": (2364, 120), "sde": (2782, 76)},
    ("ppo", "hopper"): {"gaussian": (1567, 339), "sde": (2512, 21)},
    ("ppo", "walker2d"): {"gaussian": (1230, 147), "sde": (2019, 64)},
    # SAC: DLR-RM/stable-baselines3, docs/modules/sac.rst, "Results", "PyBullet Environments":
    # 1M steps, 3 seeds, "SAC Gaussian" and "SAC gSDE" columns.
    ("sac", "halfcheetah"): {"gaussian": (2757, 53), "sde": (2984, 202)},
    ("sac", "ant"): {"gaussian": (3146, 35), "sde": (3102, 37)},
    ("sac", "hopper"): {"gaussian": (2422, 168), "sde": (2262, 1)},
    ("sac", "walker2d"): {"gaussian": (2184, 54), "sde": (2136, 67)},
}
#: Seeds behind the paper's numbers, per algorithm (the same pages).
PAPER_SEEDS = {"a2c": 6, "ppo": 6, "sac": 3}


def paper_text(algorithm: str, env: str, noise: str) -> str:
    """The paper's number for a cell as the report prints it, ``–`` for a cell beyond its table.

    Examples:
        >>> paper_text("a2c", "walker2d", "sde"), paper_text("sac", "mountaincar", "sde")
        ('839 ± 56', '–')
    """
    if (algorithm, env) not in PAPER:
        return "–"
    mean, sd = PAPER[(algorithm, env)][noise]
    return f"{mean} ± {sd}"
