"""The SAC benchmark's training: one gradient step in SB3's order (eager or compiled), TorchRL's
loop (``Collector``, ``ReplayBuffer``, ``SACLoss``) and Stable-Baselines3's, each timed whole
(wall and CPU) and evaluated at the end; a run's record.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from analysis.benchmarks.bench_sac.build import (
    BUFFER_KEYS,
    ZOO,
    compiled_suffix,
    env_dims,
    make_loss,
    make_torchrl_env,
    make_torchrl_policy,
)
from analysis.benchmarks.common import EVAL_EPISODES, first_episode_returns, gym_make, versions, write_run
from sde_torchrl.trainers.compiler import inductor_recomputing_boolean_masks
from sde_torchrl.trainers.sac import SACUpdate


def make_update(loss, sde, zoo: dict, loss_noise: str = "fresh", compile_update: bool = False):
    """One SAC gradient step on a sampled minibatch, in SB3's order (:class:`sde_torchrl.trainers.sac.SACUpdate`).

    Args:
        loss: the ``SACLoss``.
        sde: the :class:`~sde_torchrl.SDEParams` (``None`` for the Gaussian).
        zoo: the env's settings.
        loss_noise: ``"fresh"`` (:func:`~sde_torchrl.trainers.sac.fresh_loss_noise`) or ``"stored"`` (the
            buffer's ``ξ``).
        compile_update: run the whole step through ``torch.compile`` (inductor, with
            :func:`.compiler.recompute_boolean_masks`).

    Returns:
        ``update(batch)``.
    """
    update = SACUpdate(loss, sde, lr=zoo["learning_rate"], tau=zoo["tau"], loss_noise=loss_noise)
    return torch.compile(update.__call__, backend=inductor_recomputing_boolean_masks) if compile_update else update


def evaluate_torchrl(policy, env_id: str, seed: int, episodes: int = EVAL_EPISODES) -> list[float]:
    """Deterministic returns (``tanh`` of the mean) of ``episodes`` envs stepped side by side, first episode each."""
    import gymnasium as gym
    from torchrl.envs import GymWrapper
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    vec = gym.vector.SyncVectorEnv([lambda: gym_make(env_id)] * episodes,
                                   autoreset_mode=gym.vector.AutoresetMode.DISABLED)
    env = GymWrapper(vec)
    env.set_seed(seed)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.rollout(env_dims(env_id)[2], policy, auto_cast_to_device=False, break_when_any_done=False)
    env.close()
    return first_episode_returns(td["next", "reward"].reshape(episodes, -1), td["next", "done"].reshape(episodes, -1))


def train_torchrl(method: str, env_key: str, seed: int, steps: int, eval_episodes: int = EVAL_EPISODES,
                  loss_noise: str = "fresh", overrides: dict | None = None, compile_update: bool = False,
                  compile_policy: bool = False) -> dict:
    """Train ``sde`` or ``plain`` on TorchRL; returns the run's record (see the module docstring).

    ``overrides`` replaces :data:`.build.ZOO` entries (the tests' tiny runs); ``compile_update`` compiles
    the gradient step (:func:`make_update`), ``compile_policy`` the collector's policy forward
    (TorchRL's ``Collector(compile_policy=True)``).
    """
    from torchrl.collectors import Collector
    from torchrl.data import LazyTensorStorage, RandomSampler, ReplayBuffer

    zoo = {**ZOO[env_key], **(overrides or {})}
    torch.manual_seed(seed)
    obs_dim, _, _ = env_dims(zoo["env_id"])
    probe = make_torchrl_env(zoo["env_id"], seed)
    action_spec = probe.action_spec
    probe.close()
    policy, critic, sde = make_torchrl_policy(method, obs_dim, action_spec, zoo)
    env = make_torchrl_env(zoo["env_id"], seed, sde.make_tensordict_primer() if sde else None)
    loss = make_loss(policy, critic, action_spec, zoo)
    update = make_update(loss, sde, zoo, loss_noise, compile_update)
    buffer = ReplayBuffer(storage=LazyTensorStorage(min(zoo["buffer_size"], steps)), sampler=RandomSampler(),
                          batch_size=zoo["batch_size"])
    collector = Collector(env, policy, frames_per_batch=zoo["train_freq"], total_frames=steps,
                          init_random_frames=zoo["learning_starts"], auto_register_policy_transforms=True,
                          compile_policy=compile_policy)
    curve, rounds, done_frames, updates = [], [], 0, 0
    start, cpu_start = time.perf_counter(), time.process_time()
    for batch in collector:
        done_frames += batch.numel()
        finished = batch["next", "done"].reshape(-1)
        curve += [[done_frames, float(r)] for r in batch["next", "episode_reward"].reshape(-1)[finished]]
        buffer.extend(batch.reshape(-1).select(*BUFFER_KEYS, strict=False))
        if done_frames > zoo["learning_starts"]:  # SB3: train once num_timesteps > learning_starts
            round_start, round_cpu = time.perf_counter(), time.process_time()
            for _ in range(zoo["gradient_steps"]):
                update(buffer.sample())
                updates += 1
            rounds.append([time.perf_counter() - round_start, time.process_time() - round_cpu])
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    collector.shutdown()
    result = {"wall_s": wall, "cpu_s": cpu, "env_steps": done_frames, "gradient_steps": updates, "curve": curve,
              "eval_returns": evaluate_torchrl(policy, zoo["env_id"], 10_000 + seed, eval_episodes),
              "update_rounds_s": rounds}
    if sde is not None:  # σ̂ = expln(p) here, exp(p) in SB3: the same while p <= 0
        result["sde_param_max"] = float(sde.sigma_param.detach().max())
    return result


def train_sb3(env_key: str, seed: int, steps: int, use_sde: bool = True, eval_episodes: int = EVAL_EPISODES,
              overrides: dict | None = None) -> dict:
    """Train Stable-Baselines3 SAC with the zoo's settings, ``use_sde`` on or off.

    ``overrides`` replaces :data:`.build.ZOO` entries, as in :func:`train_torchrl`.
    """
    try:
        from stable_baselines3 import SAC
        from stable_baselines3.common.callbacks import BaseCallback
        from stable_baselines3.common.env_util import make_vec_env
        from stable_baselines3.common.evaluation import evaluate_policy
    except ImportError as err:
        raise SystemExit(f"bench_sac: method sb3 needs Stable-Baselines3: pip install -e '.[bench]' ({err})") from err

    zoo = {**ZOO[env_key], **(overrides or {})}
    curve: list[list[float]] = []
    round_starts: list[tuple[float, float]] = []

    class EpisodeReturns(BaseCallback):
        def _on_rollout_start(self) -> None:  # the previous round's gradient steps have ended
            round_starts.append((time.perf_counter(), time.process_time()))

        def _on_step(self) -> bool:
            curve.extend([self.num_timesteps, float(i["episode"]["r"])] for i in self.locals["infos"] if "episode" in i)
            return True

    def make():
        return gym_make(zoo["env_id"])

    env = make_vec_env(make, n_envs=1, seed=seed)
    model = SAC(
        "MlpPolicy", env, learning_rate=zoo["learning_rate"], buffer_size=zoo["buffer_size"],
        batch_size=zoo["batch_size"], ent_coef=zoo["ent_coef"], train_freq=zoo["train_freq"],
        gradient_steps=zoo["gradient_steps"], gamma=zoo["gamma"], tau=zoo["tau"],
        learning_starts=zoo["learning_starts"], use_sde=use_sde, seed=seed, device="cpu",
        policy_kwargs={"log_std_init": zoo["log_std_init"], "net_arch": zoo["net_arch"]},
    )
    start, cpu_start = time.perf_counter(), time.process_time()
    model.learn(total_timesteps=steps, callback=EpisodeReturns())
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    result = {"wall_s": wall, "cpu_s": cpu, "env_steps": int(model.num_timesteps),
              "gradient_steps": int(model._n_updates), "curve": curve, "eval_returns": [],
              "round_starts": round_starts}
    if eval_episodes:
        eval_env = make_vec_env(make, n_envs=1, seed=10_000 + seed)
        returns, _ = evaluate_policy(model, eval_env, n_eval_episodes=eval_episodes, deterministic=True,
                                     return_episode_rewards=True)
        result["eval_returns"] = [float(r) for r in returns]
    return result


def run(method: str, env_key: str, seed: int, steps: int, out: Path, loss_noise: str = "fresh",
        eval_episodes: int = EVAL_EPISODES, overrides: dict | None = None, compile_update: bool = False,
        compile_policy: bool = False) -> Path:
    """Train one method with one seed and write ``<out>/<env>_<method>_seed<k>.json``.

    Args:
        method: one of :data:`.build.METHODS`.
        env_key: one of :data:`.build.ENVS`.
        seed: the seed of the run (evaluation: ``10000 + seed``).
        steps: env steps of training.
        out: the folder of runs.
        loss_noise: ``"fresh"`` or ``"stored"`` (``sde`` only, see :func:`make_update`).
        eval_episodes: deterministic evaluation episodes at the end.
        overrides: :data:`.build.ZOO` entries replaced on both sides (a short budget's ``learning_starts``).
        compile_update: compile the TorchRL gradient step (``<out>/<env>_<method>_compiled_seed<k>.json``).
        compile_policy: with ``compile_update``, also compile the collector's policy forward
            (``<out>/<env>_<method>_compiled_policy_seed<k>.json``).

    Returns:
        The path of the written run.
    """
    torch.set_num_threads(1)  # one core per run
    if method.startswith("sb3"):
        result = train_sb3(env_key, seed, steps, use_sde=method == "sb3", eval_episodes=eval_episodes,
                           overrides=overrides)
    else:
        result = train_torchrl(method, env_key, seed, steps, loss_noise=loss_noise, eval_episodes=eval_episodes,
                               overrides=overrides, compile_update=compile_update, compile_policy=compile_policy)
    result.update(method=method, env=env_key, env_id=ZOO[env_key]["env_id"], seed=seed,
                  loss_noise=loss_noise if method == "sde" else None, compiled=compile_update,
                  compiled_policy=compile_policy,
                  settings={**ZOO[env_key], **(overrides or {})}, overrides=overrides or {},
                  env_steps_per_s=result["env_steps"] / result["wall_s"],
                  env_steps_per_cpu_s=result["env_steps"] / result["cpu_s"],
                  final_return_mean=float(np.mean(result["eval_returns"])),
                  versions=versions("stable_baselines3"))
    suffix = "_stored_noise" if method == "sde" and loss_noise == "stored" else \
        compiled_suffix(compile_update, compile_policy)
    return write_run(out / f"{env_key}_{method}{suffix}_seed{seed}.json", result)

