"""The table's cells, the budget a run is given, and the config ``train.py`` composes for a cell.

A cell is one (algorithm, env, noise, seed); its config is the experiment that trains that
algorithm on that env (:data:`EXPERIMENTS`: ``train.py +experiment=<algo>_<env>_bullet`` for the
paper's PyBullet envs, ``sac_mountaincar`` beyond them), ``explorer=gaussian`` for the Gaussian
side, with ``updates`` cut to the run's fraction of the experiment's budget and the run's extra
overrides: the same config from which :mod:`.sb3` reads the settings of the Stable-Baselines3 side.

Examples:
    >>> cell = Cell("ppo", "hopper", "gaussian", 2)
    >>> cell.name, train_overrides(cell, updates=3)
    ('ppo_hopper_gaussian_seed2', ('+experiment=ppo_hopper_bullet', 'seed=2', 'updates=3', 'explorer=gaussian'))
    >>> Cell("sac", "mountaincar", "sde", 0).experiment
    'sac_mountaincar'
    >>> updates_for(1.0, 245), updates_for(0.25, 245)
    (245, 62)
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

#: The algorithms, envs and exploration noises of the table (the gSDE paper's PyBullet table).
ALGORITHMS = ("ppo", "a2c", "sac")
ENVS = ("halfcheetah", "ant", "hopper", "walker2d")
NOISES = ("sde", "gaussian")
#: Every env a cell may have: the paper's, then those of the experiments beyond its table.
ALL_ENVS = (*ENVS, "mountaincar")
#: (algorithm, env) → the ``train.py`` experiment that trains it, with rl-baselines3-zoo's tuned
#: settings and budget (its ``n_timesteps``: for the PyBullet envs the paper's).
EXPERIMENTS = {**{(a, e): f"{a}_{e}_bullet" for a in ALGORITHMS for e in ENVS},
               ("sac", "mountaincar"): "sac_mountaincar"}
#: What a run's own overrides may not set: the cell and the fraction set them.
RESERVED = ("updates", "seed")
#: The envs' gymnasium ids, as the table names them.
ENV_IDS = {"halfcheetah": "HalfCheetahBulletEnv-v0", "ant": "AntBulletEnv-v0", "hopper": "HopperBulletEnv-v0",
           "walker2d": "Walker2DBulletEnv-v0", "mountaincar": "MountainCarContinuous-v0"}


@dataclass(frozen=True, order=True)
class Cell:
    """One run of the table, trained on both sides.

    Attributes:
        algorithm: one of :data:`ALGORITHMS`.
        env: one of :data:`ENVS`.
        noise: ``sde`` (our SDE explorer, SB3's gSDE) or ``gaussian`` (plain Gaussian noise).
        seed: the seed of both sides.
    """

    algorithm: str
    env: str
    noise: str
    seed: int

    def __post_init__(self) -> None:
        for name, allowed in (("algorithm", ALGORITHMS), ("env", ALL_ENVS), ("noise", NOISES)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name}={getattr(self, name)!r}: one of {', '.join(allowed)}")
        if (self.algorithm, self.env) not in EXPERIMENTS:
            trained = ", ".join(a for a in ALGORITHMS if (a, self.env) in EXPERIMENTS)
            raise ValueError(f"{self.algorithm} on {self.env}: no train.py experiment trains it (on {self.env}: "
                             f"{trained})")

    @property
    def name(self) -> str:
        """The cell's run name: ``<algorithm>_<env>_<noise>_seed<k>``."""
        return f"{self.algorithm}_{self.env}_{self.noise}_seed{self.seed}"

    @property
    def experiment(self) -> str:
        """The ``+experiment`` of ``train.py`` that trains it (:data:`EXPERIMENTS`)."""
        return EXPERIMENTS[(self.algorithm, self.env)]


def cells(algorithms: Iterable[str] = ALGORITHMS, envs: Iterable[str] = ENVS, noises: Iterable[str] = NOISES,
          seeds: Iterable[int] = (0,)) -> list[Cell]:
    """Every cell of the given algorithms, envs, noises and seeds, in the table's order.

    Examples:
        >>> [c.name for c in cells(["sac"], ["ant"], seeds=[0, 1])]
        ['sac_ant_sde_seed0', 'sac_ant_sde_seed1', 'sac_ant_gaussian_seed0', 'sac_ant_gaussian_seed1']
    """
    seeds = list(seeds)
    return [Cell(a, e, n, s) for a in algorithms for e in envs for n in noises for s in seeds]


def steps_per_update(conf) -> int:
    """Env steps of one update (a row of ``metrics.csv``) of a composed config: ``n_envs × n_steps``
    for PPO and A2C, ``train_freq × rounds_per_update`` for SAC."""
    alg = conf.algorithm
    if getattr(alg, "train_freq", None) is not None:
        return int(alg.train_freq * alg.rounds_per_update)
    return int(alg.n_envs * alg.n_steps)


def updates_for(fraction: float, updates: int) -> int:
    """The updates that cover ``fraction`` of an experiment's ``updates`` (the zoo's budget, which
    the experiment reaches at the first update past it, as SB3 stops): the first update past the
    fraction, and at least one.

    Examples:
        >>> updates_for(0.5, 62_500), updates_for(1e-9, 245)
        (31250, 1)
    """
    if not 0 < fraction <= 1:
        raise ValueError(f"fraction={fraction!r}: a number in (0, 1]")
    return max(1, math.ceil(fraction * updates - 1e-9))


def train_overrides(cell: Cell, updates: int | None = None, extra: Sequence[str] = ()) -> tuple[str, ...]:
    """``train.py``'s overrides for the cell: its experiment, seed, ``updates`` (if given), the
    Gaussian explorer for ``noise=gaussian``, then ``extra`` (the run's own overrides, last)."""
    overrides = [f"+experiment={cell.experiment}", f"seed={cell.seed}"]
    if updates is not None:
        overrides.append(f"updates={updates}")
    if cell.noise == "gaussian":
        overrides.append("explorer=gaussian")
    return (*overrides, *extra)


def compose_cell(cell: Cell, fraction: float, extra: Sequence[str] = ()):
    """The checked config (:func:`~sde_torchrl.config.schemas.train.validate`) that ``train.py``
    runs for the cell at ``fraction`` of its experiment's budget, with the overrides ``extra``.

    Raises:
        ValueError: ``extra`` sets ``updates`` or ``seed`` (the fraction and the cell set them).

    Returns:
        ``(conf, overrides)``: the typed config and the full list of ``train.py`` overrides.
    """
    from sde_torchrl.config.compose import compose
    from sde_torchrl.config.schemas.train import validate

    for override in extra:
        if override.split("=", 1)[0].lstrip("+~") in RESERVED:
            raise ValueError(f"override {override!r}: {' and '.join(RESERVED)} are the cell's and the fraction's "
                             "(--seeds, --fraction)")
    base = compose(list(train_overrides(cell, extra=extra)))
    updates = updates_for(fraction, base.updates)
    overrides = train_overrides(cell, updates, extra)
    return validate(compose(list(overrides))), overrides
