"""Benchmark: batched ball-catching env (with a linear SDE or REX policy in the loop) vs raw pybullet.

The policy is the paper's controller class, ``tanh(Θ x + Θ̂ x)`` (``LinearActor`` in
``make_sde_actor``), with ``Θ`` set to the arm model's scripted catching controller
(:func:`~sde_torchrl.envs.ballcatch.models.scripted_weights`) and ``σ̂ = e^-3``: the regime of
a trained policy, where the ball is held for the whole episode and every world is simulated at
every step. (A dropping policy is cheaper still: grounded worlds are frozen.) Its exploration
is SDE (``Θ̂`` drawn once per episode) or REX (``Θ̂`` redrawn at every step).

Prints ONE JSON line, all rates in world-steps per second, best of ``--repeats`` interleaved runs:

* ``env_steps_per_s``: the env with the SDE policy in the loop, collected as the trainer
  collects for this policy (:func:`sde_torchrl.collectors.rollout.linear_episode_rollout`: each world runs
  its whole episode under its map ``Θ + σ̂ ⊙ ξ``, the policy's log-likelihood tensors are
  computed for all steps afterwards);
* ``raw_steps_per_s``: time spent inside ``stepSimulation`` alone, replaying the env run's
  actions as torques (the world's own :meth:`~sde_torchrl.envs.ballcatch.world.BallCatchWorld.joint_forces`:
  each model's torque scale and transmission) on the same N worlds (the same physics regime;
  the torque calls, reads and loop are *not* counted), in whichever order is faster: world by
  world (``raw_episode_order_steps_per_s``, the order the env uses) or all worlds per step
  (``raw_lockstep_steps_per_s``); ``ratio = env_steps_per_s / raw_steps_per_s``;
* ``rex_env_steps_per_s``, ``rex_raw_steps_per_s`` and ``rex_ratio``: the same for the REX
  policy (whole episodes per world under the per-step maps ``Θ + σ̂ ⊙ ξ_t``), against the replay
  of its own actions; ``rex_step_env_steps_per_s``: REX collected by stepping all worlds together
  with a policy call per step (:func:`sde_torchrl.collectors.rollout.tensor_rollout`, REX's path before
  it ran whole episodes);
* ``raw_loop_steps_per_s``: the bare lockstep replay loop of the SDE actions,
  ``setJointMotorControlArray`` + ``stepSimulation`` per world and step;
* ``step_env_steps_per_s`` and ``step_ratio``: the env stepped for all worlds at once with the
  SDE policy called once per step (:func:`sde_torchrl.collectors.rollout.tensor_rollout`, the path for any
  other policy, and REX's before it ran whole episodes), against ``raw_lockstep_steps_per_s``;
  ``env_core_steps_per_s``: the env's own ``_step`` alone in that mode;
* ``torchrl_rollout_steps_per_s`` and ``torchrl_rollout_ratio``: the same env and SDE policy
  through ``TransformedEnv(env, InitTracker + primer).rollout`` (TorchRL's per-step machinery);
* ``policy_mean_reward`` and ``rex_policy_mean_reward``: mean reward of the timed episodes;
* with ``--workers 2``: ``parallel_env_steps_per_s``, ``env.rollout`` on a ``ParallelEnv`` of
  two batched envs (one per core) holding ``--worlds`` worlds between them.

Usage: ``python -m analysis.benchmarks.bench_ballcatch --model pybrain --worlds 16 --steps 500``
"""

from __future__ import annotations

import argparse
import json
import time

import pybullet
import torch
from tensordict import TensorDict
from torchrl.envs import Compose, InitTracker, TransformedEnv

from sde_torchrl.collectors.rollout import (
    linear_episode_env,
    linear_episode_rollout,
    noise_primer,
    tensor_rollout,
    tensor_step_env,
)
from sde_torchrl.envs.ballcatch import ARM_MODELS, BallCatchConfig, BatchedBallCatchEnv, make_parallel_ballcatch
from sde_torchrl.envs.ballcatch.models import scripted_weights
from sde_torchrl.modules.actors import LinearActor
from sde_torchrl.modules.sde import SDEParams
from sde_torchrl.modules.sde_actor import SDEActor, make_sde_actor

SIGMA_PARAM = -3.0
"""log-scale of the exploration noise of the benchmark policy (σ̂ = e^-3)."""
SCHEDULES = {"sde": "episode", "rex": "step"}
"""The noise schedule for each exploration method."""


def catching_policy(seed: int, model: str, schedule: str = "episode") -> tuple[SDEActor, SDEParams]:
    """The linear policy with ``Θ`` = the model's scripted catching controller and exploration
    redrawn per ``schedule`` (``episode``: SDE, ``step``: REX)."""
    torch.manual_seed(seed)
    actor = LinearActor(3, 4, bias=False)
    with torch.no_grad():
        actor.module.weight.copy_(torch.as_tensor(scripted_weights(model), dtype=torch.float32))
    sde = SDEParams(action_dim=4, feature_dim=3, schedule=schedule, init_param=SIGMA_PARAM)
    return make_sde_actor(actor, sde, squash=True, low=-1.0, high=1.0), sde


def joint_forces(env: BatchedBallCatchEnv, actions: torch.Tensor) -> list[list[list[float]]]:
    """Per step and world, the joint torques the env applies for ``actions [N, K, 4]``."""
    clipped = actions.clamp(-1, 1).double().tolist()
    return [[world.joint_forces(a[k]) for world, a in zip(env.worlds, clipped, strict=True)]
            for k in range(actions.shape[1])]


def time_raw(env: BatchedBallCatchEnv, forces: list[list[list[float]]], lockstep: bool) -> tuple[float, float]:
    """Replay ``forces`` (per step, per world) on the env's worlds, all worlds per step
    (``lockstep``) or each world's whole episode in turn: world-steps per second inside
    ``stepSimulation`` alone, and of the whole replay loop."""
    env.reset()
    worlds = env.worlds
    torque, step, set_torques, clock = (
        pybullet.TORQUE_CONTROL, pybullet.stepSimulation, pybullet.setJointMotorControlArray, time.perf_counter
    )
    order = ([(w, k) for k in range(len(forces)) for w in range(len(worlds))] if lockstep
             else [(w, k) for w in range(len(worlds)) for k in range(len(forces))])
    physics = 0.0
    start = clock()
    for w, k in order:
        world = worlds[w]
        set_torques(world.robot, world.joints, torque, forces=forces[k][w], physicsClientId=world.client)
        t0 = clock()
        step(physicsClientId=world.client)
        physics += clock() - t0
    loop = clock() - start
    return len(order) / physics, len(order) / loop


def time_core(env: BatchedBallCatchEnv, actions: torch.Tensor) -> float:
    """World-steps per second of the env's own ``_step`` replaying ``actions [N, K, 4]``."""
    tds = [TensorDict({"action": actions[:, k]}, batch_size=[env.num_worlds]) for k in range(actions.shape[1])]
    env.reset()
    start = time.perf_counter()
    for td in tds:
        env._step(td)
    return actions.shape[1] * env.num_worlds / (time.perf_counter() - start)


def time_collect(
    env: BatchedBallCatchEnv, steps: int, seed: int, episodes: bool, schedule: str = "episode"
) -> tuple[float, torch.Tensor, float]:
    """One collection as the trainer does it, by whole episodes per world (``episodes``) or by
    stepping all worlds together; returns ``(world-steps/s, actions [N, K, 4], mean reward)``."""
    policy, sde = catching_policy(seed, env.config.model, schedule)
    tenv = TransformedEnv(env, Compose(InitTracker(), sde.make_tensordict_primer()))
    base = linear_episode_env(tenv, policy) if episodes else tensor_step_env(tenv, policy)
    if base is None:
        raise RuntimeError(f"the {'whole-episode' if episodes else 'tensor-stepping'} path refused the policy")
    collect = linear_episode_rollout if episodes else tensor_rollout
    with torch.no_grad():
        collect(base, policy, 2, noise_primer(tenv))  # warm-up (first-call overheads)
        start = time.perf_counter()
        td = collect(base, policy, steps, noise_primer(tenv))
        elapsed = time.perf_counter() - start
    return steps * env.num_worlds / elapsed, td["action"].clone(), float(td["next", "reward"].mean())


def time_torchrl(env, steps: int, seed: int, num_worlds: int, model: str) -> float:
    """World-steps per second of ``TransformedEnv(env, ...).rollout(steps, policy)``."""
    policy, sde = catching_policy(seed, model)
    tenv = TransformedEnv(env, Compose(InitTracker(), sde.make_tensordict_primer()))
    tenv.set_seed(seed)
    with torch.no_grad():
        tenv.rollout(2, policy)
        start = time.perf_counter()
        tenv.rollout(steps, policy, break_when_any_done=False)
        elapsed = time.perf_counter() - start
    return steps * num_worlds / elapsed


def main() -> None:
    """Parse arguments, run the timings and print one JSON line."""
    parser = argparse.ArgumentParser(prog=f"python -m {__spec__.name}", description=__doc__.splitlines()[0])
    parser.add_argument("--model", choices=tuple(ARM_MODELS), default=BallCatchConfig.model, help="the arm")
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
    config = BallCatchConfig(model=args.model)
    env = BatchedBallCatchEnv(num_worlds=args.worlds, config=config, seed=args.seed)
    timings: dict[str, list[float]] = {}
    mean_reward = {}

    def record(kind: str, value: float) -> None:
        timings.setdefault(kind, []).append(value)

    try:
        for _ in range(args.repeats):  # interleaved, so background load hits all alike
            for method, schedule in SCHEDULES.items():
                sps, actions, mean_reward[method] = time_collect(env, args.steps, args.seed, True, schedule)
                record(f"{method}_env", sps)
                forces = joint_forces(env, actions)
                record(f"{method}_raw_episode", time_raw(env, forces, lockstep=False)[0])
                raw, raw_loop = time_raw(env, forces, lockstep=True)
                record(f"{method}_raw_lockstep", raw)
                record(f"{method}_raw_loop", raw_loop)
            step_sps, step_actions, _ = time_collect(env, args.steps, args.seed, episodes=False)
            record("step_env", step_sps)
            record("rex_step_env", time_collect(env, args.steps, args.seed, False, SCHEDULES["rex"])[0])
            record("core", time_core(env, step_actions))
            record("torchrl", time_torchrl(env, args.steps, args.seed, args.worlds, args.model))
    finally:
        env.close()
    best = {k: max(v) for k, v in timings.items()}
    for method in SCHEDULES:  # the raw physics in whichever order is faster
        best[f"{method}_raw"] = max(best[f"{method}_raw_episode"], best[f"{method}_raw_lockstep"])

    def rate(kind: str) -> float:
        return round(best[kind], 1)

    def ratio(kind: str, reference: str) -> float:
        return round(best[kind] / best[reference], 3)

    extra = {}
    if args.workers >= 2:
        parallel = make_parallel_ballcatch(args.workers, args.worlds // args.workers, config)
        try:
            extra["parallel_workers"] = args.workers
            extra["parallel_env_steps_per_s"] = round(
                time_torchrl(parallel, args.steps, args.seed, args.worlds, args.model), 1)
        finally:
            parallel.close()
    print(json.dumps({
        "model": args.model, "worlds": args.worlds, "steps": args.steps,
        "env_steps_per_s": rate("sde_env"), "raw_steps_per_s": rate("sde_raw"), "ratio": ratio("sde_env", "sde_raw"),
        "rex_env_steps_per_s": rate("rex_env"), "rex_raw_steps_per_s": rate("rex_raw"),
        "rex_ratio": ratio("rex_env", "rex_raw"), "rex_step_env_steps_per_s": rate("rex_step_env"),
        "raw_episode_order_steps_per_s": rate("sde_raw_episode"), "raw_lockstep_steps_per_s": rate("sde_raw_lockstep"),
        "raw_loop_steps_per_s": rate("sde_raw_loop"),
        "step_env_steps_per_s": rate("step_env"), "step_ratio": ratio("step_env", "sde_raw_lockstep"),
        "env_core_steps_per_s": rate("core"),
        "torchrl_rollout_steps_per_s": rate("torchrl"), "torchrl_rollout_ratio": ratio("torchrl", "sde_raw_lockstep"),
        "policy_mean_reward": round(mean_reward["sde"], 4), "rex_policy_mean_reward": round(mean_reward["rex"], 4),
        **extra,
    }))


if __name__ == "__main__":
    main()
