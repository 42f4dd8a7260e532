"""From a composed Hydra config to a ready :class:`~sde_torchrl.trainers.trainer.Trainer`.

The config is checked and typed once (:func:`~sde_torchrl.config.schemas.train.validate`); its groups ``env``,
``actor``, ``explorer``, ``estimator``, ``optimizer`` and ``logger`` each hold a ``_target_`` and its options.
This module supplies what only the job knows (batch sizes, the number of runs, dimensions read
off the env, per-run random streams) and wires the pieces.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import asdict
from typing import Any

import torch
from hydra.utils import instantiate
from omegaconf import DictConfig
from tensordict.nn import TensorDictSequential

from sde_torchrl.config.schemas.algorithms import SACConf
from sde_torchrl.config.schemas.train import TrainConf, loop_settings, validate
from sde_torchrl.envs.gym import FEATURES_KEY
from sde_torchrl.jobs.heap import fix_mmap_threshold
from sde_torchrl.jobs.resources import keeps_step_scores
from sde_torchrl.modules.sde_actor import make_sde_actor
from sde_torchrl.trainers.optim import exploration_parameters, make_optimizer
from sde_torchrl.trainers.trainer import Trainer
from sde_torchrl.utils.devices import training_device
from sde_torchrl.utils.rng import RunStreams

log = logging.getLogger(__name__)

#: Config groups whose chosen option labels a run's summary.
LABELLED_GROUPS = ("experiment", "env", "actor", "explorer", "estimator", "optimizer")
#: Making the envs takes longer than this: the job says what it is doing (then the trainer's
#: notice, :data:`~sde_torchrl.trainers.trainer.FIRST_UPDATE_NOTICE_S`, covers the first update).
BUILD_NOTICE_S = 5.0


def building_notice(conf: TrainConf) -> str:
    """What a job whose envs take a while to make is doing.

    Examples:
        >>> from types import SimpleNamespace as Conf
        >>> building_notice(Conf(runs=3000, episodes_per_update=10, eval_episodes=5, env=Conf(id="Pendulum-v1")))
        ... # doctest: +ELLIPSIS
        'still making the envs after 5 s: 3000 runs × (10 training + 5 evaluation) episodes side by side, ...'
    """
    name = getattr(conf.env, "id", None) or str(getattr(conf.env, "_target_", "")).rsplit(".", 1)[-1]
    return (f"still making the envs after {BUILD_NOTICE_S:g} s: {conf.runs} runs × ({conf.episodes_per_update} "
            f"training + {conf.eval_episodes} evaluation) episodes side by side, one env ({name}) each; training "
            "starts once they are made")


def build_env(conf: TrainConf, episodes: int, stream: str) -> Any:
    """Instantiates ``conf.env`` with a ``[runs, episodes]`` batch and the run streams, its
    outputs on ``conf.device``."""
    env = instantiate(conf.env, episodes=episodes, runs=conf.runs, first_run=conf.first_run, stream=stream,
                      device=conf.device)
    env.set_seed(conf.seed)
    return env


def build_trainer(cfg: DictConfig | TrainConf, out_dir: str | None = None) -> Trainer:
    """Builds env, policy, estimator, optimiser (and its learning-rate schedule) and logger for one job.

    Args:
        cfg: the composed config (see ``conf/config.yaml``), or the :class:`TrainConf` that
            :func:`~sde_torchrl.config.schemas.train.validate` made of it.
        out_dir: where the TorchRL logger writes (the run directory).

    Returns:
        The trainer; call ``train(out_dir)``.

    Raises:
        ArgumentError: for a config value that is not allowed, or a ``device`` this machine does
            not have (before anything is built).
    """
    conf = cfg if isinstance(cfg, TrainConf) else validate(cfg)
    device = training_device(conf.device)  # device=cuda without CUDA: one line, exit 2, before any env
    torch.manual_seed(conf.seed)
    notice = threading.Timer(BUILD_NOTICE_S, log.info, [building_notice(conf)])
    notice.daemon = True
    notice.start()
    try:
        env = build_env(conf, conf.episodes_per_update, "env")
        eval_env = build_env(conf, conf.eval_episodes, "eval_env")
    finally:
        notice.cancel()
    obs_dim = env.observation_spec["observation"].shape[-1]
    act_dim = env.action_spec.shape[-1]
    # The explorer's features: the observation, or what the env writes for it (a constant
    # feature appended, see sde_torchrl.envs.gym).
    feature_key = FEATURES_KEY if FEATURES_KEY in env.observation_spec.keys() else "observation"
    feature_dim = env.observation_spec[feature_key].shape[-1]

    actor = instantiate(conf.actor, in_features=obs_dim, out_features=act_dim, runs=conf.runs)
    actor.module.reset_parameters(RunStreams(conf.seed, conf.runs, "init", conf.first_run))
    streams = RunStreams(conf.seed, conf.runs, "explore", conf.first_run)
    if getattr(conf.explorer, "draws_actor_parameters", False):  # PGPE draws the actor's own parameters
        explorer = instantiate(conf.explorer, actor=actor, runs=conf.runs)
        policy = TensorDictSequential(actor, explorer)
    else:
        options = {name: value for name, value in asdict(conf.explorer).items() if name != "squash"}
        explorer = instantiate(options, action_dim=act_dim, feature_dim=feature_dim, runs=conf.runs,
                               feature_key=feature_key)
        # explorer.squash is tanh onto [-1, 1], whatever the action spec (ExplorerConf)
        policy = make_sde_actor(actor, explorer, squash=conf.explorer.squash, low=-1.0, high=1.0)
    policy.to(device)  # the parameters drawn on the CPU (per-run streams), moved once
    explorer.streams = streams
    env.append_transform(explorer.make_tensordict_primer())
    eval_env.append_transform(explorer.make_tensordict_primer())

    # The trainer collects and updates under the non-finite policy "guarded" (its FiniteGuard names
    # the update): the estimator and the env need no option for it (sde_torchrl.utils.nonfinite).
    # the estimator's schema declares its traits: whether it takes `scores` (PGPE scores its
    # parameter distribution in closed form), whether it regresses on them (ENAC)
    scores = {"scores": conf.scores} if conf.estimator.takes_scores else {}
    estimator = instantiate(conf.estimator, policy=policy, **scores)
    if conf.estimator.regresses_on_scores:
        warn_if_rank_deficient(estimator, max(conf.episodes_per_update, conf.episode_queue), conf.runs)
    optimizer, lr_schedule = make_optimizer(policy.parameters(), conf.lr, asdict(conf.optimizer), conf.updates,
                                            scale_parameters=exploration_parameters(policy))
    logger = None
    if conf.logger and out_dir is not None:
        logger = instantiate(conf.logger, log_dir=out_dir)
    def check_env(episodes: int) -> Any:  # the final check's env: the runs' own fresh episodes
        made = build_env(conf, episodes, "final_eval")
        made.append_transform(explorer.make_tensordict_primer())
        return made

    return Trainer(env, eval_env, policy, estimator, optimizer, loop_settings(conf), logger,
                   lr_schedule=lr_schedule, check_env=check_env)


def warn_if_rank_deficient(estimator: Any, episodes: int, runs: int) -> None:
    """Warns when a regression on ``[ψ, 1]`` (ENAC's) has fewer episodes than unknowns.

    Not refused, unlike REINFORCE on one episode (:class:`~sde_torchrl.config.schemas.train.TrainConf`): the
    minimum-norm solution ENAC then takes interpolates the returns and is not zero, only noisy,
    and the parameter count is known only once the policy is built.

    Args:
        estimator: the job's estimator.
        episodes: episodes per run in each regression (``N``, or the queue's ``Q``).
        runs: the job's runs (the leading dimension of run-stacked parameters).

    Examples:
        >>> from sde_torchrl import ENACEstimator, LinearActor, SDEParams, make_sde_actor
        >>> estimator = ENACEstimator(make_sde_actor(LinearActor(1, 1), SDEParams(1, 1)))
        >>> warn_if_rank_deficient(estimator, episodes=10, runs=1)  # 3 unknowns: nothing to say
    """
    unknowns = 1 + sum(p[0].numel() if p.dim() and p.shape[0] == runs else p.numel()
                       for p in estimator.learnable_parameters().values())
    if episodes < unknowns:
        log.warning("estimator=enac with %d episodes per update for %d unknowns ([ψ, 1]): the regression is "
                    "rank-deficient and its gradient noisy; use episodes_per_update (or episode_queue) >= %d",
                    episodes, unknowns, unknowns)


def run_job(conf: TrainConf, out_dir: str, choices: dict[str, str | None], progress: bool = False) -> dict[str, Any]:
    """Builds and trains (or resumes) one job; its summary is labelled with the chosen config
    options, the seed and the whole resolved config (:meth:`TrainConf.resolved`), so that a run
    directory describes itself. The trainer gets the config once, in those labels: the run
    directory records it and checks that it holds this job
    (:meth:`~sde_torchrl.jobs.run_dir.RunDirectory.check_job`).

    Args:
        conf: the job's config, validated at the edge (:func:`~sde_torchrl.config.schemas.train.validate`;
            ``train.py`` checks it before importing torch).
        out_dir: the run directory; a checkpoint there from the same config is resumed.
        choices: group → chosen option (Hydra's ``runtime.choices``).
        progress: show a progress bar.

    Returns:
        The summary written to ``summary.json``.
    """
    if keeps_step_scores(conf):  # its per-update tensors would fragment the heap: RSS +15 MB per update
        fix_mmap_threshold()
    torch.set_num_threads(conf.threads)
    labels = {group: choices.get(group) for group in LABELLED_GROUPS}
    labels.update(seed=conf.seed, config=conf.resolved())
    if isinstance(conf.algorithm, SACConf):  # SAC: the off-policy loop, the same run directory
        from sde_torchrl.config.build_sac import build_sac_trainer

        labels["algorithm"] = choices.get("algorithm")
        trainer = build_sac_trainer(conf, out_dir)
    elif conf.algorithm is not None:  # PPO: its own loop, the same run directory
        from sde_torchrl.config.build_onpolicy import build_onpolicy_trainer

        labels["algorithm"] = choices.get("algorithm")
        trainer = build_onpolicy_trainer(conf, out_dir)
    else:
        trainer = build_trainer(conf, out_dir)
    try:
        return trainer.train(out_dir, labels, checkpoint_period=conf.checkpoint_period, progress=progress)
    finally:
        trainer.close()  # a launcher's worker process may run further jobs
