"""The top-level config, :class:`TrainConf`: the settings of a job, its groups typed by their own
schemas, and the rules that tie the groups together (which explorer goes with which estimator or
algorithm, settings under which nothing could be learned); :func:`validate` turns a composed config
into these dataclasses, every value checked.

Examples:
    >>> TrainConf().updates
    200
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, is_dataclass
from typing import Any, Optional

from omegaconf import DictConfig, OmegaConf

from sde_torchrl.config.schemas.algorithms import A2CConf, SACConf
from sde_torchrl.config.schemas.envs import GymEnvConf
from sde_torchrl.config.schemas.estimators import EstimatorConf
from sde_torchrl.config.schemas.frozen import SCHEMAS, Frozen, freeze
from sde_torchrl.config.schemas.policy import (
    ExplorerConf,
    GaussianExplorerConf,
    LinearActorConf,
    MLPActorConf,
)
from sde_torchrl.jobs.resources import check_memory
from sde_torchrl.trainers.settings import TrainingSettings
from sde_torchrl.utils.checks import ArgumentError, finite, non_negative_int, one_of, positive_int
from sde_torchrl.utils.devices import check_device_name
from sde_torchrl.utils.options import ROLLOUT_SCHEDULES, SCORE_METHODS

# ``typing`` generics, not ``X | None``: OmegaConf reads these annotations at runtime.
# ruff: noqa: UP007, UP045


@dataclass
class TrainConf(Frozen, schema="config"):
    """The top-level config (``conf/config.yaml``); the groups are typed by their own schemas.

    The one form a job's config takes once composed: :func:`validate` builds it, checked and
    frozen (assigning to a field raises), at the edge (``train.py``, before torch is imported),
    and everything else is derived from it: the builders read its fields, :meth:`resolved` is
    the plain data that ``summary.json`` labels and the run directory records and checks
    (``job_config.json``, :meth:`~sde_torchrl.jobs.run_dir.RunDirectory.check_job`).

    Attributes:
        env: the ``env`` group's schema.
        actor: the ``actor`` group's schema.
        explorer: the ``explorer`` group's schema.
        estimator: the ``estimator`` group's schema.
        optimizer: the ``optimizer`` group's schema (``sgd``: eq. 1).
        logger: the ``logger`` group's schema; empty or ``null`` for none.
        algorithm: ``null``, the paper's episodic estimators (the ``estimator`` group), or the
            ``algorithm`` group's schema (``ppo``: :class:`~sde_torchrl.config.schemas.algorithms.PPOConf`,
            ``a2c``: :class:`~sde_torchrl.config.schemas.algorithms.A2CConf`, ``sac``:
            :class:`~sde_torchrl.config.schemas.algorithms.SACConf`), which trains one learner on
            ``env=gym`` with ``actor=mlp`` and ``estimator`` null; of the top-level keys it reads
            ``seed``, ``updates``, ``lr``, ``eval_period``, ``eval_episodes``, ``checkpoint_period``,
            ``progress`` and ``threads``.
        seed: job seed; run ``r``'s streams derive from ``(seed, first_run + r)``.
        runs: independent learners trained side by side in this process.
        first_run: global index of the first run (shards of a sweep).
        updates: policy updates.
        episodes_per_update: ``N``, fresh episodes per run and update.
        lr: ``α``, the base learning rate of the ``optimizer`` (with ``optimizer=sgd``, eq. 1's
            plain gradient ascent ``θ ← θ + α g``).
        eval_period: deterministic evaluation every this many updates (and after the last); 0:
            only after the last.
        eval_episodes: deterministic episodes per evaluation and run.
        final_episodes: at the job's end, its final policy and its best one (by the periodic
            evaluations, kept in ``best_policy.pt``) are each evaluated on this many fresh
            deterministic episodes per run, the same for both and drawn apart from training and
            periodic evaluation; 0: none.
        r_lim: convergence threshold on the mean exploratory return (``null``: not tracked).
        stop_at_threshold: end the job once every run has exceeded ``r_lim``.
        tensor_rollout: collect by tensor stepping where the env allows (``false``: ``env.rollout``).
        scores: how REINFORCE, ENAC and GPOMDP compute each episode's score: ``autograd``
            through the policy (any actor), or ``closed_form``, eqs. 16, 21 and 24 for a
            bias-free linear controller of the exploration features without eq. 22's Gaussian
            part (the same scores to float rounding, several times faster; another actor is
            refused when the job is built). PGPE's estimator, which scores its parameter
            distribution in closed form whatever this says, does not read it.
        episode_queue: ``Q > 0``: each update uses the last ``Q`` episodes per run (the
            ball-catching schedule); a multiple of ``episodes_per_update``.
        queue_scores: when a queued episode is scored: ``rescored``, again at every update
            under the current parameters, or ``as_collected``, once under the parameters that
            collected it (the authors' PyBrain learners; PGPE: the distribution that drew the
            parameters); needs ``episode_queue > 0``, and for PGPE plain sampling.
        checkpoint_period: write ``checkpoint.pt`` every this many updates (0: only at the end).
        progress: progress bar; ``null``: only on a terminal and outside a multirun.
        threads: torch intra-op threads per job (a job is a sequence of small ops; the jobs of a
            sweep share the cores).
        max_memory_gb: refuse a job whose estimated memory (:mod:`sde_torchrl.jobs.resources`) exceeds
            this; ``null``: the memory the machine has available when the job starts.
        device: where the job's tensors live, ``cpu`` (the default), ``cuda`` or ``cuda:N``
            (:mod:`sde_torchrl.utils.devices`; refused before anything is built where that
            device is absent).

    Examples:
        >>> TrainConf(runs=4, r_lim=-1.8).episodes_per_update
        10
        >>> TrainConf().device
        'cpu'
        >>> TrainConf(runs=4).resolved()["runs"]
        4
    """

    env: Any = None
    actor: Any = None
    explorer: Any = None
    estimator: Any = None
    optimizer: Any = None
    logger: Any = None
    algorithm: Any = None
    seed: int = 0
    runs: int = 1
    first_run: int = 0
    updates: int = 200
    episodes_per_update: int = 10
    lr: float = 0.01
    eval_period: int = 20
    eval_episodes: int = 5
    final_episodes: int = 0
    r_lim: Optional[float] = None
    stop_at_threshold: bool = False
    tensor_rollout: bool = True
    scores: str = "autograd"
    episode_queue: int = 0
    queue_scores: str = "rescored"
    checkpoint_period: int = 25
    progress: Optional[bool] = None
    threads: int = 1
    max_memory_gb: Optional[float] = None
    device: str = "cpu"

    def __post_init__(self) -> None:
        check_device_name(self.device)
        for name in ("runs", "threads"):
            positive_int(name, getattr(self, name))
        for name in ("seed", "checkpoint_period"):
            non_negative_int(name, getattr(self, name))
        if self.seed >= 2**64:  # torch seeds its generators with 64 bits
            raise ArgumentError("seed", self.seed, "an integer >= 0 and below 2**64")
        finite("lr", self.lr, minimum=0, strict=True)
        one_of("scores", self.scores, SCORE_METHODS)
        loop_settings(self)  # the training loop's own fields: TrainingSettings checks them
        if self.max_memory_gb is not None:
            finite("max_memory_gb", self.max_memory_gb, minimum=0, strict=True)
        if self.algorithm is not None:
            _check_onpolicy(self)
            return
        if isinstance(self.explorer, GaussianExplorerConf):
            raise ArgumentError("explorer", "gaussian", "an SDE or PGPE explorer for the episodic estimators "
                                                        "(explorer=gaussian is the baseline of algorithm=ppo and a2c)")
        if self.estimator is None and self.env is not None:
            options = ", ".join(schema.option for schema in SCHEMAS.values() if issubclass(schema, EstimatorConf))
            raise ArgumentError("estimator", None, f"an estimator ({options}) unless algorithm=ppo or a2c")
        _check_can_learn(self)
        _check_pgpe(self)
        _check_scores(self)
        _check_queue_scores(self)
        if self.env is not None and self.estimator is not None:
            check_memory(self)

    def resolved(self) -> dict[str, Any]:
        """The config as plain data (nested dicts and lists), each group an entry: what Hydra's
        ``OmegaConf.to_container(cfg, resolve=True)`` gives of the composed config this was
        validated from, key for key and in the same order.

        Examples:
            >>> from sde_torchrl.config.compose import compose
            >>> validate(compose(["estimator=enac"])).resolved()["estimator"]["_target_"]
            'sde_torchrl.objectives.estimators.ENACEstimator'
        """
        return asdict(self)


def loop_settings(conf: TrainConf) -> TrainingSettings:
    """The training loop's settings from the config's top level (each field of
    :class:`~sde_torchrl.trainers.settings.TrainingSettings` by its name) and the env's
    ``episode_length``; their rules are checked there, once.

    Examples:
        >>> loop_settings(TrainConf(updates=3)).updates
        3
    """
    values = {**vars(conf), "episode_length": getattr(conf.env, "episode_length", 1)}
    return TrainingSettings(**{f.name: values[f.name] for f in fields(TrainingSettings)})


def _check_onpolicy(conf: TrainConf) -> None:
    """What ``algorithm=ppo`` (``a2c``, ``sac``) trains on: one learner, a gymnasium env, an MLP
    actor, an SDE or Gaussian explorer, no episodic estimator; the SB3-style noise counts over its
    rollouts (SAC's: its rounds of ``train_freq`` steps); SAC takes a gradient step before the job ends.

    ``episodes_per_update``, which only the episodic estimators read, is refused at any value but
    its default: a config cannot tell that default from the same value set on purpose."""
    name = {A2CConf: "a2c", SACConf: "sac"}.get(type(conf.algorithm), "ppo")
    if conf.runs != 1:
        raise ArgumentError("runs", conf.runs, f"1 with algorithm={name} (one learner per job; sweep over seed "
                                               "for more)")
    default = next(f.default for f in fields(TrainConf) if f.name == "episodes_per_update")
    if conf.episodes_per_update != default:
        batch = "algorithm.train_freq env steps a round" if name == "sac" else \
            "algorithm.n_envs × algorithm.n_steps env steps an update"
        raise ArgumentError("episodes_per_update", conf.episodes_per_update,
                            f"{default} (its default) with algorithm={name}: a setting of the episodic estimators, "
                            f"which algorithm={name} does not read (it collects {batch})")
    if conf.device != "cpu":
        raise ArgumentError("device", conf.device, f"cpu with algorithm={name}")
    if conf.estimator is not None:
        target = str(getattr(conf.estimator, "_target_", "")).rsplit(".", 1)[-1]
        raise ArgumentError("estimator", target, f"null with algorithm={name} (its loss is the algorithm's): "
                                                 "estimator=null")
    if not isinstance(conf.env, GymEnvConf):
        target = str(getattr(conf.env, "_target_", "")).rsplit(".", 1)[-1]
        raise ArgumentError("env", target, f"env=gym with algorithm={name} (a gymnasium env such as "
                                           "env.id=Pendulum-v1)")
    if conf.env.normalize_obs is not None or conf.env.constant_feature:
        key = "env.normalize_obs" if conf.env.normalize_obs is not None else "env.constant_feature"
        raise ArgumentError(key, getattr(conf.env, key.split(".")[1]),
                            f"null (false) with algorithm={name}: it normalises with running statistics "
                            "(algorithm.normalize) and SDE sees the actor's last hidden layer")
    if not isinstance(conf.actor, MLPActorConf) or not conf.actor.bias:
        key, value = ("actor", str(getattr(conf.actor, "_target_", "")).rsplit(".", 1)[-1]) \
            if not isinstance(conf.actor, MLPActorConf) else ("actor.bias", False)
        raise ArgumentError(key, value, f"actor=mlp with bias with algorithm={name} (SDE's features are its "
                                        "last hidden layer)")
    if getattr(conf.explorer, "draws_actor_parameters", False):
        raise ArgumentError("explorer", "pgpe", f"an SDE explorer (sde, gsde, ...) or gaussian with algorithm={name}")
    if getattr(conf.optimizer, "sigma_lr_factor", 1.0) != 1:
        raise ArgumentError("optimizer.sigma_lr_factor", conf.optimizer.sigma_lr_factor,
                            f"1 with algorithm={name} (a rate of its own for the exploration scale is an option "
                            "of the episodic estimators' jobs)")
    rollout, steps = ("train_freq", conf.algorithm.train_freq) if name == "sac" else ("n_steps", conf.algorithm.n_steps)
    if isinstance(conf.explorer, ExplorerConf):
        if conf.explorer.schedule in ROLLOUT_SCHEDULES and conf.explorer.rollout_steps not in (None, steps):
            raise ArgumentError("explorer.rollout_steps", conf.explorer.rollout_steps,
                                f"null or algorithm.{rollout} ({steps}) with algorithm={name}: "
                                "SB3 counts the noise's steps over each rollout")
    if name == "sac":
        _check_sac_explorer(conf.explorer)
        _check_sac_learns(conf)
    check_memory(conf)


def _check_sac_explorer(explorer: Any) -> None:
    """SAC's actor is tanh-squashed; its Gaussian learns a state-dependent log-std (SB3's SAC)."""
    if not explorer.squash:
        raise ArgumentError("explorer.squash", False, "true with algorithm=sac (SAC's actor is tanh-squashed)")
    if isinstance(explorer, GaussianExplorerConf) and not explorer.learn_sigma:
        raise ArgumentError("explorer.learn_sigma", False, "true with algorithm=sac and explorer=gaussian (its "
                                                           "log-std is a learned head of the actor)")


def _check_sac_learns(conf: TrainConf) -> None:
    """SAC's first gradient step follows ``learning_starts`` env steps of random actions: a warm-up
    as long as the job (``updates × rounds_per_update × train_freq`` steps) never takes one."""
    alg = conf.algorithm
    steps = conf.updates * alg.rounds_per_update * alg.train_freq
    if alg.learning_starts >= steps:
        raise ArgumentError("algorithm.learning_starts", alg.learning_starts,
                            f"below the job's {steps:,} env steps (updates × algorithm.rounds_per_update × "
                            "algorithm.train_freq), or no gradient step is ever taken: lower it, or raise updates")


def _check_pgpe(conf: TrainConf) -> None:
    """``explorer=pgpe`` and ``estimator=pgpe`` only together; symmetric sampling on an even
    ``episodes_per_update`` (pairs ``μ ± ε``); at least two draws (the batch-mean baseline of a
    single draw cancels its return: every gradient would be exactly 0)."""
    pgpe_explorer = bool(getattr(conf.explorer, "draws_actor_parameters", False))
    pgpe_estimator = bool(getattr(conf.estimator, "carries_parameter_draws", False))
    if pgpe_explorer != pgpe_estimator:
        key = "estimator" if pgpe_explorer else "explorer"
        value = (getattr(getattr(conf, key), "_target_", "") or "").rsplit(".", 1)[-1]
        raise ArgumentError(key, value, "explorer=pgpe and estimator=pgpe go together (PGPE scores the parameter "
                                        "draws, which only explorer=pgpe makes)")
    if not pgpe_explorer:
        return
    if conf.explorer.symmetric and conf.episodes_per_update % 2:
        raise ArgumentError("episodes_per_update", conf.episodes_per_update,
                            "an even number with explorer=pgpe and explorer.symmetric=true (pairs μ ± ε), "
                            "or explorer.symmetric=false")
    draws = max(conf.episodes_per_update, conf.episode_queue) // (2 if conf.explorer.symmetric else 1)
    if draws < 2:
        raise ArgumentError("episodes_per_update", conf.episodes_per_update,
                            "at least 2 parameter draws per update with estimator=pgpe (4 episodes with "
                            "symmetric sampling): the batch-mean baseline of one draw cancels its return")


def _check_queue_scores(conf: TrainConf) -> None:
    """``queue_scores=as_collected`` but for symmetric PGPE (kept scores are for plain sampling)."""
    if conf.queue_scores == "as_collected" and getattr(conf.explorer, "symmetric", False):
        raise ArgumentError("queue_scores", "as_collected", "rescored with explorer.symmetric=true (kept scores "
                                                            "are for plain sampling; a symmetric pair is scored by "
                                                            "the difference of its draws), or explorer.symmetric=false")


def _check_scores(conf: TrainConf) -> None:
    """``scores=closed_form`` only for what eqs. 16, 21 and 24 describe: a bias-free linear
    controller of the exploration features (the observation itself) without eq. 22's Gaussian
    part; PGPE's estimator does not read the key."""
    if conf.scores != "closed_form" or not getattr(conf.estimator, "takes_scores", True):
        return
    if not isinstance(conf.actor, LinearActorConf) or conf.actor.bias:
        missing = "actor=linear with actor.bias=false"
    elif getattr(conf.explorer, "gaussian_init_param", None) is not None:
        missing = "no Gaussian part (explorer.gaussian_init_param=null)"
    elif getattr(conf.env, "constant_feature", False):
        missing = "the observation as the exploration features (env.constant_feature=false)"
    else:
        return
    raise ArgumentError("scores", "closed_form", f"autograd, or closed_form with {missing}: the closed form "
                                                 "is that of the paper's linear controller (eqs. 16, 21, 24)")


def _check_can_learn(conf: TrainConf) -> None:
    """Refuses settings under which no update can change the policy (hours of compute for nothing).

    REINFORCE's optimal baseline over a single episode equals that episode's return (GPOMDP's,
    each step's reward): with one episode per update and no queue, every gradient is exactly 0.
    ENAC with fewer episodes than parameters + 1 is not refused: its regression is rank-deficient, but the minimum-norm
    solution it then takes is not zero, only noisy: a warning once the parameters are counted
    (:func:`sde_torchrl.config.build.warn_if_rank_deficient`).
    """
    if getattr(conf.estimator, "baseline_from_batch", False) and max(conf.episodes_per_update, conf.episode_queue) < 2:
        raise ArgumentError(
            "episodes_per_update", conf.episodes_per_update,
            f"at least 2 with estimator={conf.estimator.option} (or an episode_queue of 2 or more): over a single "
            "episode the optimal baseline equals its return (GPOMDP's: each reward), so every gradient is exactly 0")



def validate(cfg: DictConfig) -> TrainConf:
    """The composed config as schema objects, every value checked and then frozen (once, at the
    edge, before anything is built): the one form of the job's config from here on.

    Args:
        cfg: the composed config.

    Returns:
        The :class:`TrainConf`, its groups as their schemas' dataclasses, interpolations
        resolved; it and its groups are frozen (:func:`~sde_torchrl.config.schemas.frozen.freeze`).

    Raises:
        ArgumentError: for the first value that is not allowed, or a key that its schema does
            not have.

    Examples:
        >>> from sde_torchrl.config.compose import compose
        >>> validate(compose(["estimator=enac"])).estimator.option
        'enac'
        >>> validate(compose(["estimator=enac", "+estimator.symmetric=true"]))  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.checks.ArgumentError: estimator.symmetric=true: unknown key (estimator=enac's options: ...)
    """
    _refuse_unknown_keys(cfg)
    return freeze(OmegaConf.to_object(cfg))


def _refuse_unknown_keys(node: DictConfig, prefix: str = "") -> None:
    """Refuses a key that the schema of its node does not have. Hydra refuses ``group.key=value``
    for such a key, but ``+group.key=value`` adds it, and ``OmegaConf.to_object`` would keep it as
    an attribute that nothing checks or reads."""
    schema = OmegaConf.get_type(node)
    names = {field.name for field in fields(schema)} if is_dataclass(schema) else None
    for key, value in node.items_ex(resolve=False):
        if names is not None and key not in names:
            raise ArgumentError(f"{prefix}{key}", value, unknown_key(prefix.rstrip("."), schema))
        if isinstance(value, DictConfig):
            _refuse_unknown_keys(value, f"{prefix}{key}.")


def unknown_key(group: str, schema: type | None) -> str:
    """What to say of a key of ``group`` that its schema does not have: for a schema that is one
    group option's own (its ``option``), that option and its keys.

    Examples:
        >>> from sde_torchrl.config.schemas.estimators import PGPEEstimatorConf
        >>> unknown_key("estimator", PGPEEstimatorConf)
        "unknown key (estimator=pgpe's options: max_grad_norm, max_grad_entry, episode_return, variance_weighted)"
        >>> unknown_key("explorer", ExplorerConf)
        'unknown key'
    """
    option = getattr(schema, "option", None)
    if option is None:
        return "unknown key"
    keys = ", ".join(field.name for field in fields(schema) if field.name != "_target_")
    return f"unknown key ({group}={option}'s options: {keys})"
