"""How long one SAC gradient step takes (``update-speed``): each method's step timed in one process,
the methods interleaved, and the TorchRL SDE step split by function (cProfile)."""

from __future__ import annotations

import time

import numpy as np
import torch

from analysis.benchmarks.bench_sac.build import METHODS, ZOO, env_dims, make_loss, make_torchrl_env, make_torchrl_policy
from analysis.benchmarks.bench_sac.report import NAMES
from analysis.benchmarks.bench_sac.train import make_update
from analysis.benchmarks.common import gym_make

#: (file, function) whose cumulative time splits a TorchRL gradient step (``update-speed --profile``).
PROFILE_PARTS = {
    "critic loss forward (SACLoss.qvalue_v2_loss)": ("objectives/sac.py", "qvalue_v2_loss"),
    "actor loss forward (SACLoss.actor_loss)": ("objectives/sac.py", "actor_loss"),
    "backward passes": ("~", "run_backward"),
    "Adam steps": ("optim/adam.py", "step"),
    "target update (SoftUpdate.step)": ("objectives/utils.py", "step"),
    "replay buffer sample": ("replay_buffers/base.py", "sample"),
    "fresh loss noise": ("trainers/sac.py", "fresh_loss_noise"),
}


def _random_transitions(n: int, obs_dim: int, action_dim: int, feature_dim: int):
    from tensordict import TensorDict

    noise = torch.randn(n, action_dim, feature_dim)
    return TensorDict({
        "observation": torch.randn(n, obs_dim), "action": torch.rand(n, action_dim) * 2 - 1, "sde_noise": noise,
        "next": {"observation": torch.randn(n, obs_dim), "reward": torch.randn(n, 1), "sde_noise": noise,
                 "done": torch.zeros(n, 1, dtype=torch.bool), "terminated": torch.zeros(n, 1, dtype=torch.bool)},
    }, [n])


def update_speed(env_key: str, updates: int, rounds: int, profile: bool = False, compile_update: bool = False) -> str:
    """Milliseconds per gradient step of each method, timed in one process, the methods interleaved.

    SB3: ``model.train(updates, batch_size)`` on a buffer filled by 1,000 collected steps; TorchRL:
    ``updates`` calls of :func:`.train.make_update`'s step on minibatches sampled from a ``ReplayBuffer`` of
    1,000 random transitions. Each round times every method once; the median over ``rounds`` is
    reported (wall and CPU), so that a neighbour's load hits all methods alike. With ``profile``,
    the TorchRL SDE step's time is split by function (cProfile, cumulative); with ``compile_update``
    the compiled SDE step (:func:`.train.make_update`) is timed too, its compilation in the warm-up round.
    """
    from stable_baselines3 import SAC
    from torchrl.data import LazyTensorStorage, RandomSampler, ReplayBuffer

    torch.set_num_threads(1)
    zoo = ZOO[env_key]
    obs_dim, action_dim, _ = env_dims(zoo["env_id"])
    action_spec = make_torchrl_env(zoo["env_id"], 0).action_spec
    steps, methods = {}, (*METHODS, *(["sde_compiled"] if compile_update else []))
    for method in methods:
        if method.startswith("sb3"):
            model = SAC("MlpPolicy", gym_make(zoo["env_id"]), learning_rate=zoo["learning_rate"],
                        batch_size=zoo["batch_size"], ent_coef=zoo["ent_coef"], gamma=zoo["gamma"], tau=zoo["tau"],
                        learning_starts=1000, use_sde=method == "sb3", seed=0, device="cpu",
                        policy_kwargs={"log_std_init": zoo["log_std_init"], "net_arch": zoo["net_arch"]})
            model.learn(1000)  # collection only (learning_starts): fills the buffer, sets up the logger
            steps[method] = lambda model=model: model.train(updates, zoo["batch_size"])
            continue
        policy, critic, sde = make_torchrl_policy(method.removesuffix("_compiled"), obs_dim, action_spec, zoo)
        update = make_update(make_loss(policy, critic, action_spec, zoo), sde, zoo,
                             compile_update=method.endswith("_compiled"))
        buffer = ReplayBuffer(storage=LazyTensorStorage(1000), sampler=RandomSampler(), batch_size=zoo["batch_size"])
        buffer.extend(_random_transitions(1000, obs_dim, action_dim, sde.feature_dim if sde else 1))

        def torchrl_steps(update=update, buffer=buffer):
            for _ in range(updates):
                update(buffer.sample())

        steps[method] = torchrl_steps
    wall, cpu = {m: [] for m in methods}, {m: [] for m in methods}
    for _ in range(rounds + 1):  # the first round warms up
        for method, step in steps.items():
            start, cpu_start = time.perf_counter(), time.process_time()
            step()
            wall[method].append(1e3 * (time.perf_counter() - start) / updates)
            cpu[method].append(1e3 * (time.process_time() - cpu_start) / updates)
    lines = [f"{zoo['env_id']}: batch {zoo['batch_size']}, net {zoo['net_arch']}, {updates} gradient steps x "
             f"{rounds} rounds (median; first round not timed)", "",
             "| method | ms / gradient step (wall) | ms / gradient step (CPU) | CPU time / SB3 counterpart's |",
             "| --- | --- | --- | --- |"]
    counterpart = {"sde": "sb3", "sde_compiled": "sb3", "plain": "sb3_gauss", "sb3": "sb3", "sb3_gauss": "sb3_gauss"}
    med = {m: (float(np.median(wall[m][1:])), float(np.median(cpu[m][1:]))) for m in methods}
    for method in methods:
        lines.append(f"| {NAMES[method]} | {med[method][0]:.1f} | {med[method][1]:.1f} | "
                     f"{med[method][1] / med[counterpart[method]][1]:.2f} |")
    if profile:
        import cProfile
        import pstats

        profiler = cProfile.Profile()
        profiler.runcall(steps["sde"])
        stats = pstats.Stats(profiler).stats
        total = max(entry[3] for entry in stats.values())
        lines += ["", f"{NAMES['sde']}: share of a gradient step (cProfile, cumulative, {updates} steps)", "",
                  "| part | share |", "| --- | --- |"]
        for label, (where, name) in PROFILE_PARTS.items():
            cumulative = sum(entry[3] for (path, _, func), entry in stats.items()
                             if where in path and (func == name or f"'{name}'" in func))
            lines.append(f"| {label} | {cumulative / total:.0%} |")
    return "\n".join(lines) + "\n"

