"""From a config with ``algorithm=sac`` to a ready :class:`~sde_torchrl.trainers.offpolicy.SACTrainer`.

The pieces, each Stable-Baselines3's ``SAC`` counterpart, so that both can be trained from one
config:

- the envs: one gymnasium env (:class:`~sde_torchrl.envs.vector.GymVectorEnv`), its training
  returns summed (``RewardSum``), then the SDE noise primer; the evaluation envs likewise,
  without the sums;
- the networks (:func:`~sde_torchrl.modules.sac_actor.make_sac_networks`): with an SDE explorer
  the SDE actor (the explorer's options, the features learned, the mean clipped, tanh-squashed),
  with ``explorer=gaussian`` SB3's state-dependent tanh-Gaussian; the critic an MLP of the same
  hidden layers;
- TorchRL's ``SACLoss`` and SB3's order of gradient steps (:mod:`sde_torchrl.trainers.sac`), the
  ``optimizer`` group (Adam) at ``lr`` for critic, actor and entropy coefficient.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

import torch
from torchrl.envs import Compose, RewardSum, TransformedEnv

from sde_torchrl.collectors.steps import StepCollector
from sde_torchrl.config.build_onpolicy import make_env, make_logger, sde_options, step_settings
from sde_torchrl.config.schemas.train import TrainConf
from sde_torchrl.modules.sac_actor import make_sac_networks
from sde_torchrl.modules.sde_actor import action_bounds
from sde_torchrl.objectives.sac import TRANSITION_KEYS, make_sac_loss
from sde_torchrl.trainers.offpolicy import OffPolicySchedule, SACTrainer, UniformActions
from sde_torchrl.trainers.sac import SACUpdate
from sde_torchrl.trainers.step_job import RECORDED_KEYS


def build_sac_trainer(conf: TrainConf, out_dir: str | None = None) -> SACTrainer:
    """Builds envs, networks, loss, optimisers, replay buffer and logger of an ``algorithm=sac``
    job from its checked config; the TorchRL logger writes into ``out_dir``. Call ``train(out_dir)``
    on the trainer it returns.

    Examples:
        >>> from sde_torchrl.config.compose import compose
        >>> from sde_torchrl.config.schemas.train import validate
        >>> conf = validate(compose(["algorithm=sac", "env=gym", "algorithm.learning_starts=4",
        ...                          "algorithm.train_freq=4", "algorithm.batch_size=4", "updates=2",
        ...                          "eval_episodes=1", "env.episode_length=10", "logger=none"]))
        >>> trainer = build_sac_trainer(conf)
        >>> trainer.update(0)["grad_norm"].tolist(), bool(trainer.update(1)["grad_norm"] > 0)
        ([0.0], True)
    """
    alg, options, logger = conf.algorithm, sde_options(conf.explorer), make_logger(conf, out_dir)
    torch.manual_seed(conf.seed)
    base, eval_base = make_env(conf, 1, "env"), make_env(conf, conf.eval_episodes, "eval_env")
    settings = step_settings(conf, "sac", 1, alg.train_freq * alg.rounds_per_update, base.episode_length)
    obs_dim, action_spec = base.observation_spec["observation"].shape[-1], base.action_spec[0]
    policy, critic, sde = make_sac_networks(obs_dim, action_spec, conf.actor.hidden,
                                            sde_options=options, activation=conf.actor.activation)
    primer = sde.make_tensordict_primer() if sde is not None else None
    env = TransformedEnv(base, Compose(RewardSum(in_keys=["reward"], out_keys=["episode_reward"]),
                                       *([primer] if primer is not None else [])))
    eval_env = TransformedEnv(eval_base, Compose(*([sde.make_tensordict_primer()] if sde is not None else [])))
    loss = make_sac_loss(policy, critic, action_spec.shape[-1], gamma=alg.gamma, ent_coef=alg.ent_coef)
    schedule = OffPolicySchedule(alg.train_freq, alg.gradient_steps, alg.learning_starts, alg.rounds_per_update,
                                 alg.batch_size, alg.buffer_size)
    update = SACUpdate(loss, sde, lr=conf.lr, tau=alg.tau, optimizer=asdict(conf.optimizer),
                       rounds=conf.updates * alg.rounds_per_update, compile=alg.compile)
    collector = StepCollector(env, policy, alg.train_freq, primer, keep=[*RECORDED_KEYS, *TRANSITION_KEYS])

    def check_env(episodes: int) -> tuple[Any, None]:  # the final check's fresh episodes
        primers = [sde.make_tensordict_primer()] if sde is not None else []
        return TransformedEnv(make_env(conf, episodes, "final_eval"), Compose(*primers)), None

    return SACTrainer(collector, eval_env, policy, loss, update, settings,
                      schedule, UniformActions(*action_bounds(action_spec)), logger=logger, check_env=check_env)


__all__ = ["build_sac_trainer"]
