"""The PPO benchmark's training: TorchRL's loop (``Collector``, ``GAE``, ``ClipPPOLoss``, the
update) and Stable-Baselines3's, each timed whole and, while ``phases`` times them, by phase; a
run's record.
"""

from __future__ import annotations

import time
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import torch

from analysis.benchmarks.bench_ppo.build import (
    ENV_ID,
    MINIBATCH_KEYS,
    ZOO,
    gym_make,
    make_normalizer,
    make_torchrl_env,
    make_torchrl_policy,
    max_episode_steps,
)
from analysis.benchmarks.bench_ppo.timing import TIMER, sb3_update_timed
from analysis.benchmarks.common import EVAL_EPISODES, first_episode_returns, versions, write_run


def make_update(loss, optim: torch.optim.Optimizer, compile_update: bool = False):
    """One PPO minibatch step: ``ClipPPOLoss``, backward, SB3's gradient-norm clip, the optimiser step.

    With ``compile_update`` the whole step goes through ``torch.compile``, as in TorchRL's own PPO
    scripts with their ``compile`` option; the first calls compile (tens of seconds).
    """

    def objective(minibatch):
        out = loss(minibatch)
        return out["loss_objective"] + out["loss_critic"]

    def clip_and_step():
        torch.nn.utils.clip_grad_norm_(loss.parameters(), ZOO["max_grad_norm"])
        optim.step()

    def update(minibatch):
        optim.zero_grad()
        objective(minibatch).backward()
        clip_and_step()

    def timed_update(minibatch):  # the same, each part timed (``phases``, eager only)
        optim.zero_grad()
        with TIMER.timed("update: loss forward"):
            value = objective(minibatch)
        with TIMER.timed("update: backward"):
            value.backward()
        with TIMER.timed("update: clip + Adam step"):
            clip_and_step()

    if compile_update:
        return torch.compile(update)
    return update if not TIMER.active else timed_update


def train_torchrl(method: str, seed: int, steps: int, compile_update: bool = False, evaluate: bool = True,
                  clip_actions: bool = True, compile_policy: bool = False) -> dict:
    """One TorchRL PPO training; ``compile_policy`` also compiles the collector's policy forward
    (TorchRL's ``Collector(compile_policy=True)``): the SDE policy's forward with the carried noise
    draws nothing, so compiling it changes no random stream."""
    from torchrl.collectors import Collector
    from torchrl.objectives import ClipPPOLoss
    from torchrl.objectives.value import GAE

    torch.manual_seed(seed)
    probe = gym_make()
    obs_dim, action_dim = probe.observation_space.shape[0], probe.action_space.shape[0]
    probe.close()
    policy, critic, sde = make_torchrl_policy(method, obs_dim, action_dim)
    normalizer = make_normalizer(obs_dim, ZOO["gamma"])
    env = make_torchrl_env(ZOO["n_envs"], seed, normalizer, sde.make_tensordict_primer() if sde else None,
                           clip_actions=clip_actions)
    loss = ClipPPOLoss(policy, critic, clip_epsilon=ZOO["clip_range"], entropy_bonus=ZOO["ent_coef"] > 0,
                       critic_coeff=ZOO["vf_coef"], loss_critic_type="l2", normalize_advantage=True)
    gae = GAE(gamma=ZOO["gamma"], lmbda=ZOO["gae_lambda"], value_network=critic, average_gae=False)
    optim = torch.optim.Adam(loss.parameters(), lr=ZOO["learning_rate"], eps=1e-5)  # SB3's Adam eps
    frames = ZOO["n_envs"] * ZOO["n_steps"]
    collector = Collector(env, policy, frames_per_batch=frames, total_frames=steps,
                          auto_register_policy_transforms=True, compile_policy=compile_policy)
    step = make_update(loss, optim, compile_update)
    curve, iteration_ends, cpu_ends, done_frames = [], [], [], 0
    start, cpu_start = time.perf_counter(), time.process_time()
    batches = iter(collector)
    while True:
        with TIMER.timed("collect"):
            batch = next(batches, None)
        if batch is None:
            break
        done_frames += batch.numel()
        finished = batch["next", "done"].squeeze(-1)
        curve += [[done_frames, float(r)] for r in batch["next", "episode_reward"].squeeze(-1)[finished]]
        with torch.no_grad(), TIMER.timed("GAE"):
            gae(batch)
        with TIMER.timed("update"):
            flat = batch.reshape(-1).select(*MINIBATCH_KEYS, strict=False).contiguous()  # only what the loss reads
            for _ in range(ZOO["n_epochs"]):
                for idx in torch.randperm(flat.numel()).split(ZOO["batch_size"]):
                    with TIMER.timed("update: minibatch indexing"):
                        minibatch = flat[idx]
                    step(minibatch)
        iteration_ends.append(time.perf_counter() - start)
        cpu_ends.append(time.process_time() - cpu_start)
        if len(iteration_ends) == 1:
            TIMER.restart()  # the first iteration (warm-up, compilation) is not timed
    wall = time.perf_counter() - start
    collector.shutdown()
    return {"wall_s": wall, "env_steps": done_frames, "curve": curve, "iteration_ends_s": iteration_ends,
            "iteration_cpu_ends_s": cpu_ends,
            "eval_returns": evaluate_torchrl(policy, normalizer, 10_000 + seed, clip_actions) if evaluate else []}


def evaluate_torchrl(policy, normalizer, seed: int, clip_actions: bool = True) -> list[float]:
    """Deterministic returns of ``EVAL_EPISODES`` episodes, frozen observation statistics, raw rewards."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    frozen = make_normalizer(normalizer.obs_mean.shape[0], ZOO["gamma"])
    frozen.load_state_dict(normalizer.state_dict())
    frozen.training_stats, frozen.normalize_reward = False, False
    env = make_torchrl_env(EVAL_EPISODES, seed, frozen, clip_actions=clip_actions)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.rollout(max_episode_steps(), policy, auto_cast_to_device=False, break_when_any_done=False)
    env.close()
    return first_episode_returns(td["next", "reward"].squeeze(-1), td["next", "done"].squeeze(-1))



def train_job(rollouts: int, overrides: tuple[str, ...] = ()) -> dict:
    """``rollouts`` updates of ``python train.py +experiment=ppo_halfcheetah_bullet`` (the job's
    own trainer: its collector, checks and update, no evaluation or files), each update's end
    in wall and CPU seconds and each rollout's collection time."""
    from sde_torchrl.config.build_onpolicy import build_onpolicy_trainer
    from sde_torchrl.config.compose import compose
    from sde_torchrl.config.schemas.train import validate

    conf = validate(compose(["+experiment=ppo_halfcheetah_bullet", "logger=none", *overrides]))
    trainer = build_onpolicy_trainer(conf)
    collect_s: list[float] = []
    rollout = trainer.collector.rollout

    def timed_rollout():
        begin = time.perf_counter()
        batch = rollout()
        collect_s.append(time.perf_counter() - begin)
        return batch

    trainer.collector.rollout = timed_rollout
    if TIMER.active:
        _time_job_phases(trainer)
    ends, cpu_ends, start, cpu_start = [], [], time.perf_counter(), time.process_time()
    for k in range(rollouts):
        trainer.update(k)
        ends.append(time.perf_counter() - start)
        cpu_ends.append(time.process_time() - cpu_start)
        if k == 0:
            TIMER.restart()  # the first iteration (warm-up, compilation) is not timed
    trainer.close()
    return {"iteration_ends_s": ends, "iteration_cpu_ends_s": cpu_ends, "collect_s": collect_s}


def _time_job_phases(trainer) -> None:
    """Times the job's phases under ``phases``' names: its collection and, within it, pybullet's
    step, the policy's forward and the env's transforms; GAE; the update (compiled: timed whole)."""
    timed = TIMER.wrap
    collector = trainer.collector
    collector.rollout = timed("collect", collector.rollout)
    for env in collector.env.base_env.envs:
        env.step = timed("collect: pybullet step", env.step)
    collector.policy = timed("collect: policy forward", collector.policy)
    for transform in collector.env.transform:
        transform._step = timed("collect: env transforms", transform._step)
    trainer.advantage = timed("GAE", trainer.advantage)
    trainer.update_step = timed("update", trainer.update_step)


def train_sb3(seed: int, steps: int, use_sde: bool = True, evaluate: bool = True) -> dict:
    """One Stable-Baselines3 PPO training with the zoo's settings, gSDE (``use_sde``) or its Gaussian."""
    try:
        from stable_baselines3 import PPO
        from stable_baselines3.common.callbacks import BaseCallback
        from stable_baselines3.common.env_util import make_vec_env
        from stable_baselines3.common.evaluation import evaluate_policy
        from stable_baselines3.common.vec_env import VecNormalize
    except ImportError as err:
        raise SystemExit(f"bench_ppo: method sb3 needs Stable-Baselines3: pip install -e '.[bench]' ({err})") from err

    curve: list[list[float]] = []
    iteration_ends: list[float] = []
    cpu_ends: list[float] = []
    collect_s: list[float] = []

    class EpisodeReturns(BaseCallback):
        def _on_rollout_start(self) -> None:  # the previous iteration's update has ended
            self.collect_start = time.perf_counter()
            if self.num_timesteps:
                iteration_ends.append(time.perf_counter() - start)
                cpu_ends.append(time.process_time() - cpu_start)
                TIMER.mark("update")
                if len(iteration_ends) == 1:
                    TIMER.restart()  # the first iteration is not timed
            TIMER.mark(None)

        def _on_rollout_end(self) -> None:
            collect_s.append(time.perf_counter() - self.collect_start)
            TIMER.mark("collect")

        def _on_step(self) -> bool:
            curve.extend([self.num_timesteps, float(i["episode"]["r"])] for i in self.locals["infos"] if "episode" in i)
            return True

    env = VecNormalize(make_vec_env(gym_make, n_envs=ZOO["n_envs"], seed=seed), gamma=ZOO["gamma"])
    model = PPO(
        "MlpPolicy", env, n_steps=ZOO["n_steps"], batch_size=ZOO["batch_size"], gamma=ZOO["gamma"],
        gae_lambda=ZOO["gae_lambda"], n_epochs=ZOO["n_epochs"], ent_coef=ZOO["ent_coef"], use_sde=use_sde,
        sde_sample_freq=ZOO["sde_sample_freq"], max_grad_norm=ZOO["max_grad_norm"], vf_coef=ZOO["vf_coef"],
        learning_rate=ZOO["learning_rate"], clip_range=ZOO["clip_range"], seed=seed, device="cpu",
        policy_kwargs={"log_std_init": ZOO["log_std_init"], "ortho_init": False, "activation_fn": torch.nn.ReLU,
                       "net_arch": {"pi": ZOO["net_arch"], "vf": ZOO["net_arch"]}},
    )
    start, cpu_start = time.perf_counter(), time.process_time()
    with sb3_update_timed(model) if TIMER.active else nullcontext():
        model.learn(total_timesteps=steps, callback=EpisodeReturns())
    TIMER.mark("update")  # the last iteration's update
    wall = time.perf_counter() - start
    iteration_ends.append(wall)
    cpu_ends.append(time.process_time() - cpu_start)
    if not evaluate:
        return {"wall_s": wall, "env_steps": int(model.num_timesteps), "iteration_ends_s": iteration_ends,
                "iteration_cpu_ends_s": cpu_ends, "collect_s": collect_s}
    eval_env = VecNormalize(make_vec_env(gym_make, n_envs=1, seed=10_000 + seed), training=False, norm_reward=False)
    eval_env.obs_rms = env.obs_rms
    returns, _ = evaluate_policy(model, eval_env, n_eval_episodes=EVAL_EPISODES, deterministic=True,
                                 return_episode_rewards=True)
    return {"wall_s": wall, "env_steps": int(model.num_timesteps), "curve": curve, "iteration_ends_s": iteration_ends,
            "eval_returns": [float(r) for r in returns]}



def run(method: str, seed: int, steps: int, out: Path, compile_update: bool = False, clip_actions: bool = True) -> Path:
    """Train one method with one seed on one thread; writes and returns ``<out>/<method>_seed<k>.json``."""
    torch.set_num_threads(1)  # one core per run: two runs side by side on a 2-core machine
    if method.startswith("sb3"):
        result = train_sb3(seed, steps, use_sde=method == "sb3")
    else:
        result = train_torchrl(method, seed, steps, compile_update, clip_actions=clip_actions)
    torchrl_method = not method.startswith("sb3")
    result.update(method=method, seed=seed, compiled=compile_update and torchrl_method,
                  clipped_actions=clip_actions or not torchrl_method,  # SB3 always clips
                  env_id=ENV_ID, settings=ZOO,
                  env_steps_per_s=result["env_steps"] / result["wall_s"],
                  final_return_mean=float(np.mean(result["eval_returns"])),
                  versions=versions())
    return write_run(out / f"{method}_seed{seed}.json", result)
