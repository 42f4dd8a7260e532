"""Benchmark: batched ball-catching env (with a linear SDE policy in the loop) vs raw pybullet.

Prints ONE JSON line:

* ``raw_steps_per_s``: world-steps per second of a loop that calls only ``stepSimulation`` on the
  same N worlds (same model, reset the same way, torques zero);
* ``raw_torque_steps_per_s``: the same loop, also applying the env's recorded torques with one
  ``setJointMotorControlArray`` per world and step (same physics trajectory as the env run);
* ``env_core_steps_per_s``: the env's own ``_step`` alone, replaying the env run's actions (the env's share of the
  overhead, without TorchRL's ``step``/``rollout`` machinery, transforms or policy);
* ``env_steps_per_s``: world-steps per second of ``TransformedEnv(BatchedBallCatchEnv,
  InitTracker + noise primer).rollout(K, policy)`` with the policy ``tanh(Θ x + (σ̂ ⊙ ξ) x)``
  (``LinearActor`` + ``StateDependentExplorer``, noise drawn once per episode);
* ``ratio`` = ``env_steps_per_s / raw_steps_per_s``;
* ``tensor_rollout_steps_per_s`` and ``tensor_rollout_ratio``: the same env and policy collected
  by :func:`sde_torchrl.rollout.tensor_rollout`, the trainer's path (no per-step TensorDicts);
* with ``--workers 2``: ``parallel_env_steps_per_s``, the same policy on a ``ParallelEnv`` of two
  batched envs (one per core) holding ``--worlds`` worlds between them.

Timings are the best of ``--repeats`` interleaved runs; torch runs single-threaded.

Usage: ``python analysis/bench_ballcatch.py --worlds 16 --steps 500``
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import pybullet
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.envs import Compose, InitTracker, TransformedEnv

from sde_torchrl.actors import LinearActor
from sde_torchrl.envs.ballcatch import DISTAL_TORQUE_RATIO
from sde_torchrl.envs.ballcatch_torchrl import BatchedBallCatchEnv, make_parallel_ballcatch
from sde_torchrl.exploration import StateDependentExplorer
from sde_torchrl.rollout import tensor_rollout, tensor_step_env


def time_raw(env: BatchedBallCatchEnv, steps: int, forces: np.ndarray | None = None) -> float:
    """World-steps per second of bare ``stepSimulation`` (optionally preceded by torques)."""
    env.reset()
    clients = [w.client for w in env.worlds]
    start = time.perf_counter()
    if forces is None:
        for _ in range(steps):
            for cid in clients:
                pybullet.stepSimulation(physicsClientId=cid)
    else:
        torque = pybullet.TORQUE_CONTROL
        for k in range(steps):
            for i, world in enumerate(env.worlds):
                pybullet.setJointMotorControlArray(
                    world.robot, world.joints, torque, forces=forces[i, k].tolist(), physicsClientId=world.client
                )
                pybullet.stepSimulation(physicsClientId=world.client)
    return steps * len(clients) / (time.perf_counter() - start)


def time_core(env: BatchedBallCatchEnv, actions: torch.Tensor) -> float:
    """World-steps per second of the env's own ``_step`` (validation, physics, reward, TensorDict)
    replaying recorded ``actions [N, K, 4]``: the env's share of the overhead, without TorchRL's
    wrappers or a policy."""
    steps = actions.shape[1]
    tds = [TensorDict({"action": actions[:, k]}, batch_size=[env.num_worlds]) for k in range(steps)]
    env.reset()
    start = time.perf_counter()
    for td in tds:
        env._step(td)
    return steps * env.num_worlds / (time.perf_counter() - start)


def time_env(env: BatchedBallCatchEnv, steps: int, seed: int) -> tuple[float, torch.Tensor, float]:
    """World-steps per second through the TorchRL env with the linear SDE policy.

    Returns:
        ``(steps per second, actions [N, K, 4], mean reward)``.
    """
    torch.manual_seed(seed)
    actor = LinearActor(3, 4, bias=False)
    explorer = StateDependentExplorer(action_dim=4, feature_dim=3, squash=True)
    policy = TensorDictSequential(actor, explorer)
    tenv = TransformedEnv(env, Compose(InitTracker(), explorer.make_tensordict_primer()))
    tenv.set_seed(seed)
    with torch.no_grad():
        tenv.rollout(2, policy)  # warm-up (first-call overheads)
        start = time.perf_counter()
        td = tenv.rollout(steps, policy, break_when_any_done=False)
        elapsed = time.perf_counter() - start
    return steps * env.num_worlds / elapsed, td["action"].clone(), float(td["next", "reward"].mean())


def time_tensor(env: BatchedBallCatchEnv, steps: int, seed: int) -> float:
    """World-steps per second of the same policy on the same env collected by
    :func:`sde_torchrl.rollout.tensor_rollout` (what the trainer uses), without per-step
    TensorDicts."""
    torch.manual_seed(seed)
    explorer = StateDependentExplorer(action_dim=4, feature_dim=3, squash=True)
    policy = TensorDictSequential(LinearActor(3, 4, bias=False), explorer)
    tenv = TransformedEnv(env, Compose(InitTracker(), explorer.make_tensordict_primer()))
    base = tensor_step_env(tenv, policy)
    with torch.no_grad():
        tensor_rollout(base, policy, 2)
        start = time.perf_counter()
        tensor_rollout(base, policy, steps)
        elapsed = time.perf_counter() - start
    return steps * env.num_worlds / elapsed


def joint_forces(env: BatchedBallCatchEnv, actions: torch.Tensor) -> np.ndarray:
    """The ``[N, K, 11]`` joint torques the env applies for ``actions [N, K, 4]``."""
    scaled = (actions.clamp(-1, 1).double() * torch.tensor(env.config.max_torques, dtype=torch.float64)).numpy()
    fingers = np.tile(scaled[..., 3:] * np.array([1.0, DISTAL_TORQUE_RATIO]), 4)
    return np.concatenate([scaled[..., :3], fingers], axis=-1)


def time_parallel(workers: int, worlds: int, steps: int, seed: int) -> float:
    """World-steps per second of :func:`make_parallel_ballcatch` (``workers`` processes) with the policy."""
    if worlds % workers:
        raise ValueError(f"--worlds ({worlds}) must be divisible by --workers ({workers})")
    env = make_parallel_ballcatch(workers, worlds // workers)
    try:
        torch.manual_seed(seed)
        explorer = StateDependentExplorer(action_dim=4, feature_dim=3, squash=True)
        policy = TensorDictSequential(LinearActor(3, 4, bias=False), explorer)
        tenv = TransformedEnv(env, Compose(InitTracker(), explorer.make_tensordict_primer()))
        tenv.set_seed(seed)
        with torch.no_grad():
            tenv.rollout(2, policy)
            start = time.perf_counter()
            tenv.rollout(steps, policy, break_when_any_done=False)
            elapsed = time.perf_counter() - start
    finally:
        env.close()
    return steps * worlds / elapsed


def main() -> None:
    """Parse arguments, run the three timings and print one JSON line."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=16)
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--workers", type=int, default=0,
        help="if >= 2, also time a ParallelEnv of this many processes sharing the --worlds",
    )
    parser.add_argument("--repeats", type=int, default=3, help="best of this many timings of each kind")
    args = parser.parse_args()
    torch.set_num_threads(1)
    env = BatchedBallCatchEnv(num_worlds=args.worlds, seed=args.seed)
    env_sps, raw_sps, raw_torque_sps, core_sps, tensor_sps = [], [], [], [], []
    try:
        for _ in range(args.repeats):  # interleaved, so background load hits all three alike
            sps, actions, mean_reward = time_env(env, args.steps, args.seed)
            env_sps.append(sps)
            raw_sps.append(time_raw(env, args.steps))
            raw_torque_sps.append(time_raw(env, args.steps, joint_forces(env, actions)))
            core_sps.append(time_core(env, actions))
            tensor_sps.append(time_tensor(env, args.steps, args.seed))
    finally:
        env.close()
    env_sps, raw_sps, raw_torque_sps = max(env_sps), max(raw_sps), max(raw_torque_sps)
    core_sps, tensor_sps = max(core_sps), max(tensor_sps)
    extra = {}
    if args.workers >= 2:
        extra["parallel_workers"] = args.workers
        extra["parallel_env_steps_per_s"] = round(time_parallel(args.workers, args.worlds, args.steps, args.seed), 1)
    print(json.dumps({
        "worlds": args.worlds,
        "steps": args.steps,
        "raw_steps_per_s": round(raw_sps, 1),
        "raw_torque_steps_per_s": round(raw_torque_sps, 1),
        "env_core_steps_per_s": round(core_sps, 1),
        "env_steps_per_s": round(env_sps, 1),
        "ratio": round(env_sps / raw_sps, 3),
        "ratio_vs_raw_torque": round(env_sps / raw_torque_sps, 3),
        "tensor_rollout_steps_per_s": round(tensor_sps, 1),
        "tensor_rollout_ratio": round(tensor_sps / raw_sps, 3),
        "policy_mean_reward": round(mean_reward, 4),
        **extra,
    }))


if __name__ == "__main__":
    main()
