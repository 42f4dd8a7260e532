"""The SAC benchmark's envs and networks: rl-baselines3-zoo's settings per env (:data:`ZOO`), the
env wrapped by TorchRL, the actor (``sde`` or ``plain``) and critic, the loss with SB3's settings,
and the name a run's compilation adds to its file.

Examples:
    >>> sorted(METHODS), sorted(ENVS)
    (['plain', 'sb3', 'sb3_gauss', 'sde'], ['halfcheetah', 'mountaincar'])
"""

from __future__ import annotations

from analysis.benchmarks.common import gym_make
from sde_torchrl.modules.sac_actor import make_sac_networks
from sde_torchrl.trainers.sac import make_sac_loss

#: The four methods (the report adds rows: compiled runs, the stored-noise ablation).
METHODS = ("sde", "plain", "sb3", "sb3_gauss")
#: The SDE noise of the SAC losses: a fresh matrix per gradient step (SB3) or the buffer's.
LOSS_NOISE = ("fresh", "stored")
#: rl-baselines3-zoo hyperparams/sac.yml (tuned entries); ``train_freq`` is also our SDE resampling
#: period: SB3's SAC (``sde_sample_freq=-1``) redraws the noise at the start of every collection.
ZOO = {
    "mountaincar": {
        "env_id": "MountainCarContinuous-v0", "n_timesteps": 50_000, "learning_rate": 3e-4, "buffer_size": 50_000,
        "batch_size": 512, "ent_coef": 0.1, "train_freq": 32, "gradient_steps": 32, "gamma": 0.9999, "tau": 0.01,
        "learning_starts": 0, "use_sde": True, "log_std_init": -3.67, "net_arch": [64, 64],
    },
    "halfcheetah": {
        "env_id": "HalfCheetahBulletEnv-v0", "n_timesteps": 1_000_000, "learning_rate": 7.3e-4,
        "buffer_size": 300_000, "batch_size": 256, "ent_coef": "auto", "train_freq": 8, "gradient_steps": 8,
        "gamma": 0.98, "tau": 0.02, "learning_starts": 10_000, "use_sde": True, "log_std_init": -3.0,
        "net_arch": [400, 300],
    },
}
#: The envs, by key.
ENVS = tuple(ZOO)
#: What the losses read of a transition (the SDE policy's noise only with gSDE).
BUFFER_KEYS = ("observation", "action", ("next", "observation"), ("next", "reward"), ("next", "done"),
               ("next", "terminated"), "sde_noise", ("next", "sde_noise"))


def env_dims(env_id: str) -> tuple[int, int, int]:
    """The env's observation size, action size and episode length."""
    env = gym_make(env_id)
    dims = env.observation_space.shape[0], env.action_space.shape[0], int(env.spec.max_episode_steps)
    env.close()
    return dims


def make_torchrl_policy(method: str, obs_dim: int, action_spec, zoo: dict):
    """The actor (``sde`` or ``plain``), the critic and the :class:`~sde_torchrl.SDEParams` (``None`` for plain):
    :func:`sde_torchrl.modules.sac_actor.make_sac_networks` with ``zoo["net_arch"]``, the SDE noise redrawn
    every ``train_freq`` steps and at resets (``schedule="every_n"``), ``p`` initialised to ``log_std_init``.

    Args:
        method: ``"sde"`` or ``"plain"``.
        obs_dim: observation size.
        action_spec: the env's (bounded) action spec.
        zoo: the env's settings (:data:`ZOO`).
    """
    options = None if method == "plain" else {"schedule": "every_n", "every_n": zoo["train_freq"],
                                              "init_param": zoo["log_std_init"]}
    return make_sac_networks(obs_dim, action_spec, zoo["net_arch"], sde_options=options)


def make_loss(policy, critic, action_spec, zoo: dict):
    """TorchRL's ``SACLoss`` with SB3's settings (:func:`sde_torchrl.trainers.sac.make_sac_loss`)."""
    return make_sac_loss(policy, critic, action_spec.shape[-1], gamma=zoo["gamma"], ent_coef=zoo["ent_coef"])


def make_torchrl_env(env_id: str, seed: int, primer=None):
    """The env wrapped by TorchRL, training-episode returns summed (``episode_reward``)."""
    from torchrl.envs import Compose, GymEnv, RewardSum, TransformedEnv

    if "Bullet" in env_id:
        import pybullet_envs_gymnasium  # noqa: F401
    env = TransformedEnv(GymEnv(env_id), Compose(RewardSum(in_keys=["reward"], out_keys=["episode_reward"]),
                                                 *([primer] if primer is not None else [])))
    env.set_seed(seed)
    return env


def compiled_suffix(compiled: bool, compiled_policy: bool) -> str:
    """What a run's compilation adds to its file name and its report row.

    Examples:
        >>> compiled_suffix(True, True), compiled_suffix(True, False), compiled_suffix(False, False)
        ('_compiled_policy', '_compiled', '')
    """
    return "_compiled" * compiled + "_policy" * (compiled and compiled_policy)

