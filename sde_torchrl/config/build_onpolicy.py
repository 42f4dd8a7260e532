"""From a config with ``algorithm=ppo`` (or ``a2c``) to a ready :class:`~sde_torchrl.trainers.onpolicy.OnPolicyTrainer`.

The pieces, each Stable-Baselines3's counterpart, so that both can be trained from one composed
config:

- the envs: ``n_envs`` gymnasium envs (:class:`~sde_torchrl.envs.vector.GymVectorEnv`), the raw
  training returns summed (``RewardSum``) before SB3's running normalisation
  (:class:`~sde_torchrl.envs.normalize.RunningNormalize`, with ``algorithm.normalize``), then the
  SDE noise primer; the evaluation envs with the statistics frozen and raw rewards;
- the policy: with an SDE explorer, :func:`~sde_torchrl.modules.sde_actor.make_sde_actor` over a
  :class:`~sde_torchrl.modules.actors.LatentMLPActor` whose last hidden layer, detached, gives the
  noise its features (gSDE's ``learn_features=False``); with ``explorer=gaussian``,
  :func:`~sde_torchrl.modules.gaussian.make_gaussian_actor` over an
  :class:`~sde_torchrl.modules.actors.MLPActor`; the critic an MLP of the same shape;
- TorchRL's ``GAE`` (as :class:`~sde_torchrl.objectives.gae.RolloutGAE` computes it) and
  ``ClipPPOLoss`` (:mod:`sde_torchrl.trainers.ppo`) or ``A2CLoss`` (:mod:`sde_torchrl.trainers.a2c`),
  one optimiser over policy and critic;
- the collector keeping of each step what the loop, ``GAE`` and the loss read.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

import torch
from hydra.utils import instantiate
from torch import nn
from torchrl.envs import Compose, RewardSum, TransformedEnv
from torchrl.modules import MLP, ValueOperator

from sde_torchrl.collectors.steps import StepCollector
from sde_torchrl.config.schemas.algorithms import A2CConf
from sde_torchrl.config.schemas.policy import ExplorerConf, GaussianExplorerConf
from sde_torchrl.config.schemas.train import TrainConf
from sde_torchrl.envs.normalize import RunningNormalize
from sde_torchrl.envs.vector import GymVectorEnv
from sde_torchrl.modules.actors import LatentMLPActor, MLPActor
from sde_torchrl.modules.gaussian import make_gaussian_actor
from sde_torchrl.modules.sde import SDEParams
from sde_torchrl.modules.sde_actor import make_sde_actor
from sde_torchrl.objectives.actor_critic import make_a2c_loss, make_ppo_loss
from sde_torchrl.objectives.gae import RolloutGAE
from sde_torchrl.trainers.a2c import A2CUpdate
from sde_torchrl.trainers.onpolicy import OnPolicyTrainer
from sde_torchrl.trainers.optim import make_optimizer
from sde_torchrl.trainers.ppo import PPOUpdate
from sde_torchrl.trainers.step_job import RECORDED_KEYS, StepSettings

#: The actor's activation names → torch's classes (for the critic).
ACTIVATION_CLASSES = {"relu": nn.ReLU, "tanh": nn.Tanh, "sigmoid": nn.Sigmoid}
#: Where the SDE policy's actor writes the exploration features.
FEATURE_KEY = "sde_features"


def make_env(conf: TrainConf, n_envs: int, stream: str) -> GymVectorEnv:
    """``n_envs`` envs of ``conf.env`` (``env=gym``) with the job's seed on ``stream``."""
    env = conf.env
    return GymVectorEnv(env.id, n_envs, env.episode_length, stream=stream, seed=conf.seed,
                        gym_kwargs=dict(env.gym_kwargs or {}), reset_options=env.reset_options,
                        time_feature=conf.algorithm.time_feature)


def sde_options(explorer: Any) -> dict[str, Any] | None:
    """``SDEParams``'s keyword arguments from an SDE explorer's config; ``None`` for the Gaussian.

    Examples:
        >>> sde_options(ExplorerConf(schedule="rollout", init_param=-3.0))["init_param"]
        -3.0
    """
    if not isinstance(explorer, ExplorerConf):
        return None
    return {name: value for name, value in asdict(explorer).items() if name not in ("_target_", "squash")}


def step_settings(conf: TrainConf, algorithm: str, n_envs: int, n_steps: int, episode_length: int) -> StepSettings:
    """The loop's settings of a PPO, A2C or SAC job (``n_steps``: steps per env and update)."""
    return StepSettings(algorithm, updates=conf.updates, n_envs=n_envs, n_steps=n_steps,
                        eval_period=conf.eval_period, eval_episodes=conf.eval_episodes, episode_length=episode_length,
                        first_run=conf.first_run, final_episodes=conf.final_episodes)


def make_logger(conf: TrainConf, out_dir: str | None) -> Any:
    """The job's TorchRL logger writing into ``out_dir`` (``None`` without one or without a directory)."""
    return instantiate(conf.logger, log_dir=out_dir) if conf.logger and out_dir is not None else None


def make_policy(conf: TrainConf, obs_dim: int, act_dim: int) -> tuple[nn.Module, SDEParams | None]:
    """The exploring policy of ``conf.explorer`` over ``conf.actor``, and its SDE module (``None``
    for the Gaussian); with ``squash``, tanh onto ``[-1, 1]``."""
    actor_conf, explorer = conf.actor, conf.explorer
    options = {"activation": actor_conf.activation, "init": actor_conf.init}
    if isinstance(explorer, GaussianExplorerConf):
        actor = MLPActor(obs_dim, act_dim, actor_conf.hidden, **options)
        return make_gaussian_actor(actor, act_dim, init_param=explorer.init_param, learn_sigma=explorer.learn_sigma,
                                   squash=explorer.squash), None
    assert isinstance(explorer, ExplorerConf)  # the schema's rule (_check_onpolicy)
    actor = LatentMLPActor(obs_dim, act_dim, actor_conf.hidden, feature_key=FEATURE_KEY, **options)
    sde = SDEParams(act_dim, actor.feature_dim, feature_key=FEATURE_KEY, **sde_options(explorer))
    return make_sde_actor(actor, sde, squash=explorer.squash, low=-1.0, high=1.0), sde


def make_critic(conf: TrainConf, obs_dim: int) -> ValueOperator:
    """The value network: an MLP with ``algorithm.critic_hidden`` (or the actor's) hidden layers."""
    hidden = conf.algorithm.critic_hidden if conf.algorithm.critic_hidden is not None else conf.actor.hidden
    net = MLP(in_features=obs_dim, out_features=1, num_cells=list(hidden),
              activation_class=ACTIVATION_CLASSES[conf.actor.activation])
    return ValueOperator(net, in_keys=["observation"])


def build_onpolicy_trainer(conf: TrainConf, out_dir: str | None = None) -> OnPolicyTrainer:
    """Builds envs, policy, critic, loss, optimiser and logger of an ``algorithm=ppo`` or ``a2c`` job.

    Args:
        conf: the checked config (:func:`~sde_torchrl.config.schemas.train.validate`).
        out_dir: where the TorchRL logger writes (the run directory).

    Returns:
        The trainer; call ``train(out_dir)``.

    Examples:
        >>> from sde_torchrl.config.compose import compose
        >>> from sde_torchrl.config.schemas.train import validate
        >>> conf = validate(compose(["algorithm=ppo", "env=gym", "algorithm.n_steps=8", "algorithm.batch_size=4",
        ...                          "updates=1", "eval_episodes=1", "env.episode_length=10", "logger=none"]))
        >>> trainer = build_onpolicy_trainer(conf)
        >>> trainer.update(0)["return_mean"].shape
        torch.Size([1])
    """
    alg, a2c, logger = conf.algorithm, isinstance(conf.algorithm, A2CConf), make_logger(conf, out_dir)
    torch.manual_seed(conf.seed)
    base, eval_base = make_env(conf, alg.n_envs, "env"), make_env(conf, conf.eval_episodes, "eval_env")
    settings = step_settings(conf, "a2c" if a2c else "ppo", alg.n_envs, alg.n_steps, base.episode_length)
    obs_dim, act_dim = base.observation_spec["observation"].shape[-1], base.action_spec.shape[-1]
    policy, sde = make_policy(conf, obs_dim, act_dim)
    critic = make_critic(conf, obs_dim)
    normalizer = RunningNormalize(obs_dim, alg.n_envs, alg.gamma) if alg.normalize else None
    eval_normalizer = normalizer.frozen(conf.eval_episodes) if normalizer is not None else None
    primer = sde.make_tensordict_primer() if sde is not None else None
    env = TransformedEnv(base, Compose(RewardSum(in_keys=["reward"], out_keys=["episode_reward"]),
                                       *[t for t in (normalizer, primer) if t is not None]))
    eval_transforms = [t for t in (eval_normalizer, sde.make_tensordict_primer() if sde else None) if t is not None]
    eval_env = TransformedEnv(eval_base, Compose(*eval_transforms))

    if a2c:
        loss = make_a2c_loss(policy, critic, ent_coef=alg.ent_coef, vf_coef=alg.vf_coef)
    else:
        loss = make_ppo_loss(policy, critic, clip_range=alg.clip_range, ent_coef=alg.ent_coef, vf_coef=alg.vf_coef,
                             normalize_advantage=alg.normalize_advantage)
    advantage = RolloutGAE(gamma=alg.gamma, lmbda=alg.gae_lambda, value_network=critic, average_gae=False)
    optimizer, lr_schedule = make_optimizer(loss.parameters(), conf.lr, asdict(conf.optimizer), conf.updates,
                                            fused=alg.compile)
    if a2c:
        update: Any = A2CUpdate(loss, optimizer, max_grad_norm=alg.max_grad_norm,
                                normalize_advantage=alg.normalize_advantage, compile=alg.compile)
    else:
        update = PPOUpdate(loss, optimizer, n_epochs=alg.n_epochs, batch_size=alg.batch_size,
                           max_grad_norm=alg.max_grad_norm, clip_range_schedule=alg.clip_range_schedule,
                           updates=conf.updates, compile=alg.compile)
    keep = [*RECORDED_KEYS, *advantage.in_keys, *update.in_keys]

    def check_env(episodes: int) -> tuple[Any, RunningNormalize | None]:  # the final check's fresh episodes
        frozen = normalizer.frozen(episodes) if normalizer is not None else None
        transforms = [t for t in (frozen, sde.make_tensordict_primer() if sde else None) if t is not None]
        return TransformedEnv(make_env(conf, episodes, "final_eval"), Compose(*transforms)), frozen

    return OnPolicyTrainer(StepCollector(env, policy, alg.n_steps, primer, keep), eval_env, policy, critic, advantage,
                           update, optimizer, settings, normalizer=normalizer, eval_normalizer=eval_normalizer,
                           logger=logger, lr_schedule=lr_schedule, check_env=check_env)


__all__ = ["build_onpolicy_trainer", "make_critic", "make_env", "make_logger", "make_policy", "sde_options",
           "step_settings"]
