"""From a composed Hydra config to a ready :class:`~sde_torchrl.trainer.Trainer`.

The config groups ``env``, ``actor``, ``explorer``, ``estimator`` and ``logger`` each hold a
``_target_`` and its options; this module supplies what only the job knows (batch sizes, the
number of runs, dimensions read off the env, per-run random streams) and wires the pieces.
"""

from __future__ import annotations

from typing import Any

import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from tensordict.nn import TensorDictSequential

from sde_torchrl.config import register_configs, validate
from sde_torchrl.envs.minimize import midway_threshold

#: Key of extra exploration features an env may write (``sde_torchrl.envs.gym.FEATURES_KEY``).
FEATURES_KEY = "sde_features"
from sde_torchrl.rng import RunStreams
from sde_torchrl.settings import TrainingSettings
from sde_torchrl.trainer import Trainer

#: Config groups whose chosen option labels a run's summary.
LABELLED_GROUPS = ("experiment", "env", "actor", "explorer", "estimator")


def register_resolvers() -> None:
    """Config resolvers (``${midway_r_lim:T,x0,s,noise_std,theta0}``, see ``midway_threshold``)
    and the config schemas of :mod:`sde_torchrl.config`: call before composing a config."""
    register_configs()
    OmegaConf.register_new_resolver(
        "midway_r_lim",
        lambda T, x0, s, noise, theta0: midway_threshold(int(T), float(x0), float(s), float(noise), float(theta0)),
        replace=True,
    )


def build_env(cfg: DictConfig, episodes: int, stream: str) -> Any:
    """Instantiates ``cfg.env`` with a ``[runs, episodes]`` batch and the run streams."""
    env = instantiate(cfg.env, episodes=episodes, runs=cfg.runs, first_run=cfg.first_run,
                      stream=stream)
    env.set_seed(cfg.seed)
    return env


def build_trainer(cfg: DictConfig, out_dir: str | None = None) -> Trainer:
    """Builds env, policy, estimator, optimiser and logger for one job.

    Args:
        cfg: the composed config (see ``conf/config.yaml``).
        out_dir: where the TorchRL logger writes (the run directory).

    Returns:
        The trainer; call ``train(out_dir)``.
    """
    validate(cfg)
    torch.manual_seed(cfg.seed)
    env = build_env(cfg, cfg.episodes_per_update, "env")
    eval_env = build_env(cfg, cfg.eval_episodes, "eval_env")
    obs_dim = env.observation_spec["observation"].shape[-1]
    act_dim = env.action_spec.shape[-1]
    # The explorer's features: the observation, or what the env writes for it (a constant
    # feature appended, see sde_torchrl.envs.gym).
    feature_key = FEATURES_KEY if FEATURES_KEY in env.observation_spec.keys() else "observation"
    feature_dim = env.observation_spec[feature_key].shape[-1]

    actor = instantiate(cfg.actor, in_features=obs_dim, out_features=act_dim, runs=cfg.runs)
    actor.module.reset_parameters(RunStreams(cfg.seed, cfg.runs, "init", cfg.first_run))
    explorer = instantiate(cfg.explorer, action_dim=act_dim, feature_dim=feature_dim, runs=cfg.runs,
                           feature_key=feature_key)
    explorer.streams = RunStreams(cfg.seed, cfg.runs, "explore", cfg.first_run)
    env.append_transform(explorer.make_tensordict_primer())
    eval_env.append_transform(explorer.make_tensordict_primer())
    policy = TensorDictSequential(actor, explorer)

    estimator = instantiate(cfg.estimator, policy=policy)
    optimizer = torch.optim.SGD(policy.parameters(), lr=cfg.lr)
    logger = None
    if cfg.get("logger") and out_dir is not None:
        logger = instantiate(cfg.logger, log_dir=out_dir)
    settings = TrainingSettings(
        updates=cfg.updates, episodes_per_update=cfg.episodes_per_update,
        episode_length=cfg.env.episode_length, eval_period=cfg.eval_period,
        eval_episodes=cfg.eval_episodes, r_lim=cfg.r_lim, first_run=cfg.first_run,
        stop_at_threshold=cfg.stop_at_threshold, tensor_rollout=cfg.tensor_rollout,
        episode_queue=cfg.episode_queue,
    )
    return Trainer(env, eval_env, policy, estimator, optimizer, settings, logger)


def run_job(
    cfg: DictConfig, out_dir: str, choices: dict[str, str | None], progress: bool = False,
) -> dict[str, Any]:
    """Builds and trains (or resumes) one job; its summary is labelled with the chosen config
    options, the seed and the whole resolved config, so that a run directory describes itself.

    Args:
        cfg: the composed config.
        out_dir: the run directory; a checkpoint there from the same config is resumed.
        choices: group → chosen option (Hydra's ``runtime.choices``).
        progress: show a progress bar.

    Returns:
        The summary written to ``summary.json``.

    Raises:
        ConfigError: for a config value that is not allowed (before anything is built).
    """
    validate(cfg)
    torch.set_num_threads(cfg.threads)
    config = OmegaConf.to_container(cfg, resolve=True)
    labels = {group: choices.get(group) for group in LABELLED_GROUPS}
    labels.update(seed=cfg.seed, config=config)
    trainer = build_trainer(cfg, out_dir)
    try:
        return trainer.train(out_dir, labels, config=config,
                             checkpoint_period=cfg.get("checkpoint_period", 0), progress=progress)
    finally:
        trainer.close()  # a launcher's worker process may run further jobs
