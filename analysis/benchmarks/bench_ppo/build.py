"""The PPO benchmark's env and policies: rl-baselines3-zoo's settings (:data:`ZOO`), the Bullet
envs stepped side by side under SB3 ``VecNormalize``'s rule as a TorchRL transform, and the
TorchRL actors (``plain`` Gaussian or ``sde``) with their critic.

Examples:
    >>> sorted(METHODS)
    ['plain', 'sb3', 'sb3_gauss', 'sde']
"""

from __future__ import annotations

import torch

from analysis.benchmarks import common
from analysis.benchmarks.bench_ppo.timing import TIMER
from sde_torchrl.envs.normalize import running_update

#: The env every method trains on.
ENV_ID = "HalfCheetahBulletEnv-v0"
#: The four methods, each one row of the report.
METHODS = ("plain", "sde", "sb3", "sb3_gauss")
#: rl-baselines3-zoo hyperparams/ppo.yml, "HalfCheetahBulletEnv-v0" (tuned, PPO + gSDE)
ZOO = {
    "n_envs": 16, "n_steps": 512, "batch_size": 128, "gamma": 0.99, "gae_lambda": 0.9, "n_epochs": 20,
    "ent_coef": 0.0, "sde_sample_freq": 4, "max_grad_norm": 0.5, "vf_coef": 0.5, "learning_rate": 3e-5,
    "clip_range": 0.4, "log_std_init": -2.0, "net_arch": [256, 256], "normalize": True,
}
CLIP, EPS = 10.0, 1e-8  # VecNormalize's clip_obs = clip_reward and epsilon
#: What ClipPPOLoss reads of a minibatch: not the SDE noise ξ, which the likelihood (eq. 20) does not
#: read (an A × S matrix per sample that would be gathered 20 times per iteration for nothing).
MINIBATCH_KEYS = ("observation", "action", "action_log_prob", "advantage", "value_target", "state_value", "is_init")


def gym_make():
    """One :data:`ENV_ID` env; while :data:`~analysis.benchmarks.bench_ppo.timing.TIMER` is on,
    its steps are timed as pybullet's share of collection."""
    import gymnasium as gym

    env = common.gym_make(ENV_ID)
    if not TIMER.active:
        return env

    class TimedStep(gym.Wrapper):  # the physics' share of collection: pybullet's own step
        def step(self, action):
            with TIMER.timed("collect: pybullet step"):
                return self.env.step(action)

    return TimedStep(env)


def max_episode_steps() -> int:
    """The length of an :data:`ENV_ID` episode."""
    env = gym_make()
    steps = env.spec.max_episode_steps
    env.close()
    return int(steps)


def make_normalizer(obs_dim: int, gamma: float):
    """SB3 ``VecNormalize``'s rule as a TorchRL transform (observations and discounted-return scale)."""
    from torchrl.envs import Transform

    class ZooNormalize(Transform):
        def __init__(self) -> None:
            super().__init__(in_keys=["observation"], out_keys=["observation"])
            self.register_buffer("obs_mean", torch.zeros(obs_dim, dtype=torch.float64))
            self.register_buffer("obs_var", torch.ones(obs_dim, dtype=torch.float64))
            self.register_buffer("obs_count", torch.tensor(1e-4, dtype=torch.float64))
            self.register_buffer("ret_mean", torch.zeros((), dtype=torch.float64))
            self.register_buffer("ret_var", torch.ones((), dtype=torch.float64))
            self.register_buffer("ret_count", torch.tensor(1e-4, dtype=torch.float64))
            self.training_stats, self.normalize_reward, self.returns = True, True, None

        def _norm(self, obs):
            scaled = (obs.double() - self.obs_mean) / (self.obs_var + EPS).sqrt()
            return scaled.clamp(-CLIP, CLIP).to(obs.dtype)

        def _reset(self, tensordict, tensordict_reset):
            tensordict_reset.set("observation", self._norm(tensordict_reset.get("observation")))
            return tensordict_reset

        def _step(self, tensordict, next_tensordict):
            obs, reward = next_tensordict.get("observation"), next_tensordict.get("reward")
            if self.training_stats:
                self.obs_mean, self.obs_var, self.obs_count = running_update(
                    self.obs_mean, self.obs_var, self.obs_count, obs)
            next_tensordict.set("observation", self._norm(obs))
            if self.normalize_reward:
                if self.returns is None:
                    self.returns = torch.zeros_like(reward, dtype=torch.float64)
                self.returns = self.returns * gamma + reward.double()
                if self.training_stats:
                    self.ret_mean, self.ret_var, self.ret_count = running_update(
                        self.ret_mean, self.ret_var, self.ret_count, self.returns)
                scaled = (reward.double() / (self.ret_var + EPS).sqrt()).clamp(-CLIP, CLIP)
                next_tensordict.set("reward", scaled.to(reward.dtype))
                self.returns = torch.where(next_tensordict.get("done"), 0.0, self.returns)
            return next_tensordict

    return ZooNormalize()


def make_torchrl_env(n_envs: int, seed: int, normalizer, primer=None, clip_actions: bool = True):
    """16 Bullet envs in one gymnasium ``SyncVectorEnv``, wrapped by TorchRL, raw returns summed.

    The env steps with the action clipped to its bounds while the batch keeps the sampled one,
    as SB3 does (``np.clip`` before ``env.step``, the unclipped action in the rollout buffer):
    pybullet's locomotion envs clip the torque but charge their electricity and stall costs on
    the action they are given, so an unclipped action outside ``[-1, 1]`` is a different reward.
    ``clip_actions=False`` steps with the sampled action (the first sweep's setup, for the ablation).
    """
    import gymnasium as gym
    from torchrl.envs import ClipTransform, Compose, GymWrapper, RewardSum, TransformedEnv

    vec = gym.vector.SyncVectorEnv([gym_make] * n_envs, autoreset_mode=gym.vector.AutoresetMode.DISABLED)
    low, high = vec.single_action_space.low, vec.single_action_space.high
    if low.min() != low.max() or high.min() != high.max():
        raise ValueError(f"{ENV_ID}: action bounds differ per dimension ({low}, {high}); ClipTransform takes scalars")
    base = GymWrapper(vec)
    base.set_seed(seed)
    clip = ClipTransform(in_keys_inv=["action"], out_keys_inv=["action"], low=float(low[0]), high=float(high[0]))
    transforms = [*([clip] if clip_actions else []), RewardSum(in_keys=["reward"], out_keys=["episode_reward"]),
                  normalizer]
    return TransformedEnv(base, Compose(*transforms, *([primer] if primer is not None else [])))


def make_torchrl_policy(method: str, obs_dim: int, action_dim: int):
    """The actor (``plain`` Gaussian or ``sde``) and the critic, SB3's architecture (no shared layers).

    Both actors are ``2 × 256`` ReLU MLPs with a linear output (``torch.nn.Linear``'s initial
    distribution, as SB3 with ``ortho_init=False``); the SDE one also writes its last hidden
    layer, detached, as the exploration features (:class:`~sde_torchrl.modules.actors.LatentMLPActor`).
    """
    from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule, TensorDictSequential
    from torch import nn
    from torchrl.modules import MLP, IndependentNormal, ProbabilisticActor, ValueOperator

    from sde_torchrl import LatentMLPActor, MLPActor, SDEParams, make_sde_actor

    hidden = ZOO["net_arch"]
    critic = ValueOperator(MLP(in_features=obs_dim, out_features=1, num_cells=hidden, activation_class=nn.ReLU),
                           in_keys=["observation"])
    if method == "plain":
        scale = TensorDictModule(AddStateIndependentNormalScale(action_dim, init_value=ZOO["log_std_init"]),
                                 in_keys=["loc"], out_keys=["loc", "scale"])
        actor = MLPActor(obs_dim, action_dim, hidden, activation="relu")
        policy = ProbabilisticActor(TensorDictSequential(actor, scale), in_keys=["loc", "scale"],
                                    distribution_class=IndependentNormal, return_log_prob=True)
        return policy, critic, None
    actor = LatentMLPActor(obs_dim, action_dim, hidden, activation="relu", feature_key="sde_features")
    sde = SDEParams(action_dim, actor.feature_dim, schedule="every_n", every_n=ZOO["sde_sample_freq"],
                    init_param=ZOO["log_std_init"], feature_key="sde_features")
    return make_sde_actor(actor, sde), critic, sde

