"""Benchmark: batched ball-catching env (with a linear SDE policy in the loop) vs raw pybullet.

The policy is the paper's controller class, ``tanh(Θ x + (σ̂ ⊙ ξ) x)`` (``LinearActor`` +
``StateDependentExplorer``, noise drawn once per episode), with ``Θ`` set to the shipped
catching controller (:data:`~sde_torchrl.envs.ballcatch.SCRIPTED_WEIGHTS`) and ``σ̂ = e^-3``:
the regime of a trained policy, where the ball is held for the whole episode and every world
is simulated at every step. (A dropping policy is cheaper still: grounded worlds are frozen.)

Prints ONE JSON line, all rates in world-steps per second, best of ``--repeats`` interleaved runs:

* ``raw_steps_per_s``: time spent inside ``stepSimulation`` alone, replaying the env run's
  torques on the same N worlds (so the physics is the same trajectory; the torque calls and
  the loop are *not* counted: the strictest denominator);
* ``raw_loop_steps_per_s``: the bare replay loop, ``setJointMotorControlArray`` + ``stepSimulation``
  per world and step;
* ``env_core_steps_per_s``: the env's own ``_step`` alone, replaying the same actions (validation,
  physics, the two position reads the reward needs, TensorDict out);
* ``env_steps_per_s``: the env with the policy in the loop, collected as the trainer collects
  (:func:`sde_torchrl.rollout.tensor_rollout`: the env's ``transition`` and the policy's
  tensors, no per-step TensorDict); ``ratio`` = ``env_steps_per_s / raw_steps_per_s``;
* ``torchrl_rollout_steps_per_s`` and ``torchrl_rollout_ratio``: the same env and policy through
  ``TransformedEnv(env, InitTracker + primer).rollout`` (TorchRL's per-step machinery);
* with ``--workers 2``: ``parallel_env_steps_per_s``, ``env.rollout`` on a ``ParallelEnv`` of
  two batched envs (one per core) holding ``--worlds`` worlds between them.

Usage: ``python analysis/bench_ballcatch.py --worlds 16 --steps 500``
"""

from __future__ import annotations

import argparse
import json
import time

import pybullet
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.envs import Compose, InitTracker, TransformedEnv

from sde_torchrl.actors import LinearActor
from sde_torchrl.envs.ballcatch import SCRIPTED_WEIGHTS, joint_torques
from sde_torchrl.envs.ballcatch_torchrl import BatchedBallCatchEnv, make_parallel_ballcatch
from sde_torchrl.exploration import StateDependentExplorer
from sde_torchrl.rollout import tensor_rollout, tensor_step_env

SIGMA_PARAM = -3.0
"""log-scale of the exploration noise of the benchmark policy (σ̂ = e^-3)."""


def catching_policy(seed: int) -> tuple[TensorDictSequential, StateDependentExplorer]:
    """The linear SDE policy with ``Θ`` = the scripted catching controller."""
    torch.manual_seed(seed)
    actor = LinearActor(3, 4, bias=False)
    with torch.no_grad():
        actor.module.weight.copy_(torch.as_tensor(SCRIPTED_WEIGHTS, dtype=torch.float32))
    explorer = StateDependentExplorer(action_dim=4, feature_dim=3, squash=True, init_param=SIGMA_PARAM)
    return TensorDictSequential(actor, explorer), explorer


def joint_forces(env: BatchedBallCatchEnv, actions: torch.Tensor) -> list[list[list[float]]]:
    """Per step and world, the 11 joint torques the env applies for ``actions [N, K, 4]``."""
    scaled = (actions.clamp(-1, 1).double() * torch.tensor(env.config.max_torques, dtype=torch.float64)).numpy()
    return [joint_torques(scaled[:, k]).tolist() for k in range(scaled.shape[1])]


def time_raw(env: BatchedBallCatchEnv, forces: list[list[list[float]]]) -> tuple[float, float]:
    """Replay ``forces`` on the env's worlds: world-steps per second inside ``stepSimulation``
    alone, and of the whole replay loop."""
    env.reset()
    worlds = env.worlds
    torque, step, set_torques, clock = (
        pybullet.TORQUE_CONTROL, pybullet.stepSimulation, pybullet.setJointMotorControlArray, time.perf_counter
    )
    physics = 0.0
    start = clock()
    for per_world in forces:
        for world, f in zip(worlds, per_world):
            set_torques(world.robot, world.joints, torque, forces=f, physicsClientId=world.client)
            t0 = clock()
            step(physicsClientId=world.client)
            physics += clock() - t0
    loop = clock() - start
    count = len(forces) * len(worlds)
    return count / physics, count / loop


def time_core(env: BatchedBallCatchEnv, actions: torch.Tensor) -> float:
    """World-steps per second of the env's own ``_step`` replaying ``actions [N, K, 4]``."""
    tds = [TensorDict({"action": actions[:, k]}, batch_size=[env.num_worlds]) for k in range(actions.shape[1])]
    env.reset()
    start = time.perf_counter()
    for td in tds:
        env._step(td)
    return actions.shape[1] * env.num_worlds / (time.perf_counter() - start)


def time_tensor(env: BatchedBallCatchEnv, steps: int, seed: int) -> tuple[float, torch.Tensor, float]:
    """The trainer's collection path; returns ``(world-steps/s, actions [N, K, 4], mean reward)``."""
    policy, explorer = catching_policy(seed)
    tenv = TransformedEnv(env, Compose(InitTracker(), explorer.make_tensordict_primer()))
    base = tensor_step_env(tenv, policy)
    with torch.no_grad():
        tensor_rollout(base, policy, 2)  # warm-up (first-call overheads)
        start = time.perf_counter()
        td = tensor_rollout(base, policy, steps)
        elapsed = time.perf_counter() - start
    return steps * env.num_worlds / elapsed, td["action"].clone(), float(td["next", "reward"].mean())


def time_torchrl(env, steps: int, seed: int, num_worlds: int) -> float:
    """World-steps per second of ``TransformedEnv(env, ...).rollout(steps, policy)``."""
    policy, explorer = catching_policy(seed)
    tenv = TransformedEnv(env, Compose(InitTracker(), explorer.make_tensordict_primer()))
    tenv.set_seed(seed)
    with torch.no_grad():
        tenv.rollout(2, policy)
        start = time.perf_counter()
        tenv.rollout(steps, policy, break_when_any_done=False)
        elapsed = time.perf_counter() - start
    return steps * num_worlds / elapsed


def main() -> None:
    """Parse arguments, run the timings and print one JSON line."""
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
    if args.workers >= 2 and args.worlds % args.workers:
        parser.error(f"--worlds ({args.worlds}) must be divisible by --workers ({args.workers})")
    torch.set_num_threads(1)
    env = BatchedBallCatchEnv(num_worlds=args.worlds, seed=args.seed)
    timings: dict[str, list[float]] = {k: [] for k in ("env", "raw", "raw_loop", "core", "torchrl")}
    try:
        for _ in range(args.repeats):  # interleaved, so background load hits all alike
            sps, actions, mean_reward = time_tensor(env, args.steps, args.seed)
            timings["env"].append(sps)
            raw, raw_loop = time_raw(env, joint_forces(env, actions))
            timings["raw"].append(raw)
            timings["raw_loop"].append(raw_loop)
            timings["core"].append(time_core(env, actions))
            timings["torchrl"].append(time_torchrl(env, args.steps, args.seed, args.worlds))
    finally:
        env.close()
    best = {k: max(v) for k, v in timings.items()}
    extra = {}
    if args.workers >= 2:
        parallel = make_parallel_ballcatch(args.workers, args.worlds // args.workers)
        try:
            extra["parallel_workers"] = args.workers
            extra["parallel_env_steps_per_s"] = round(time_torchrl(parallel, args.steps, args.seed, args.worlds), 1)
        finally:
            parallel.close()
    print(json.dumps({
        "worlds": args.worlds,
        "steps": args.steps,
        "raw_steps_per_s": round(best["raw"], 1),
        "raw_loop_steps_per_s": round(best["raw_loop"], 1),
        "env_core_steps_per_s": round(best["core"], 1),
        "env_steps_per_s": round(best["env"], 1),
        "ratio": round(best["env"] / best["raw"], 3),
        "torchrl_rollout_steps_per_s": round(best["torchrl"], 1),
        "torchrl_rollout_ratio": round(best["torchrl"] / best["raw"], 3),
        "policy_mean_reward": round(mean_reward, 4),
        **extra,
    }))


if __name__ == "__main__":
    main()
