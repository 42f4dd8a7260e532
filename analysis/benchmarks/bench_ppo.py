"""PPO on HalfCheetahBullet: TorchRL with a plain Gaussian or the SDE policy, against SB3 PPO + gSDE.

Three methods, the same hyperparameters (rl-baselines3-zoo's tuned PPO + gSDE settings for
``HalfCheetahBulletEnv-v0``, :data:`ZOO`), the same observation and reward normalisation rule
(SB3's ``VecNormalize``), 16 envs stepped in one process:

* ``plain``: TorchRL ``Collector`` + ``GAE`` + ``ClipPPOLoss``, state-independent Gaussian
  (``AddStateIndependentNormalScale``, log-std initialised to ``log_std_init``);
* ``sde``: the same loop with the SDE policy (:func:`sde_torchrl.make_sde_actor`): features ``x``
  from the actor's last hidden layer (detached, as gSDE's ``learn_features=False``), noise matrix
  redrawn every ``sde_sample_freq`` steps and at every reset (``schedule="every_n"``),
  ``p`` initialised to ``log_std_init`` (``σ̂ = expln(p) = exp(p)`` for ``p ≤ 0``);
* ``sb3``: Stable-Baselines3 ``PPO(use_sde=True)`` (optional extra ``.[bench]``);
* ``sb3_gauss``: the same without gSDE (SB3's state-independent Gaussian), to compare PPO loops
  apart from the exploration.

Each run writes ``<out>/<method>_seed<k>.json``: the deterministic return of 10 evaluation
episodes at the end (frozen observation statistics, raw rewards), the training episodes' raw
returns against env steps, and env steps per wall-clock second of the whole training (collection
and updates, evaluation excluded). ``report`` turns a folder of runs into a table and a plot;
``speed`` times single iterations per variant, ``phases`` splits them into collection (pybullet's
share), GAE and the update's parts.

Usage::

    python -m analysis.benchmarks.bench_ppo run --method sde --seed 0 --steps 500000 --out docs/ppo/runs
    python -m analysis.benchmarks.bench_ppo report docs/ppo/runs --out docs/ppo
    python -m analysis.benchmarks.bench_ppo phases sb3 sde+compile sde --rollouts 4 --out docs/ppo/phases.md

Examples:
    >>> sorted(METHODS)
    ['plain', 'sb3', 'sb3_gauss', 'sde']
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch

from analysis.figures import binned_curve, ratio_of_means, saved_figure
from sde_torchrl.envs.normalize import running_update
from sde_torchrl.utils.intervals import bootstrap_interval

ENV_ID = "HalfCheetahBulletEnv-v0"
METHODS = ("plain", "sde", "sb3", "sb3_gauss")
#: ``+compile``: the update compiled; ``+compile+policy``: the collector's policy forward as well.
SPEED_VARIANTS = ("plain", "plain+compile", "plain+compile+policy", "sde", "sde+compile", "sde+compile+policy", "sb3",
                  "sb3_gauss")
EVAL_EPISODES = 10
# rl-baselines3-zoo hyperparams/ppo.yml, "HalfCheetahBulletEnv-v0" (tuned, PPO + gSDE)
ZOO = {
    "n_envs": 16, "n_steps": 512, "batch_size": 128, "gamma": 0.99, "gae_lambda": 0.9, "n_epochs": 20,
    "ent_coef": 0.0, "sde_sample_freq": 4, "max_grad_norm": 0.5, "vf_coef": 0.5, "learning_rate": 3e-5,
    "clip_range": 0.4, "log_std_init": -2.0, "net_arch": [256, 256], "normalize": True,
}
CLIP, EPS = 10.0, 1e-8  # VecNormalize's clip_obs = clip_reward and epsilon
#: What ClipPPOLoss reads of a minibatch: not the SDE noise ξ, which the likelihood (eq. 20) does not
#: read (an A × S matrix per sample that would be gathered 20 times per iteration for nothing).
MINIBATCH_KEYS = ("observation", "action", "action_log_prob", "advantage", "value_target", "state_value", "is_init")


#: Seconds per phase of training, accumulated while ``phases`` runs (``None``: not timed).
TIMER: dict[str, float] | None = None


@contextmanager
def _timed(phase: str):
    """Add the block's wall time to ``TIMER[phase]`` (a no-op unless ``phases`` is timing)."""
    if TIMER is None:
        yield
        return
    start = time.perf_counter()
    yield
    TIMER[phase] = TIMER.get(phase, 0.0) + time.perf_counter() - start


def _gym_make():
    import gymnasium as gym
    import pybullet_envs_gymnasium  # noqa: F401  (registers the Bullet envs)

    env = gym.make(ENV_ID)
    if TIMER is None:
        return env

    class TimedStep(gym.Wrapper):  # the physics' share of collection: pybullet's own step
        def step(self, action):
            with _timed("collect: pybullet step"):
                return self.env.step(action)

    return TimedStep(env)


# ----------------------------------------------------------------------------------- TorchRL side
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

    vec = gym.vector.SyncVectorEnv([_gym_make] * n_envs, autoreset_mode=gym.vector.AutoresetMode.DISABLED)
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


def evaluate_torchrl(policy, normalizer, seed: int, clip_actions: bool = True) -> list[float]:
    """Deterministic returns of ``EVAL_EPISODES`` episodes, frozen observation statistics, raw rewards."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    frozen = make_normalizer(normalizer.obs_mean.shape[0], ZOO["gamma"])
    frozen.load_state_dict(normalizer.state_dict())
    frozen.training_stats, frozen.normalize_reward = False, False
    env = make_torchrl_env(EVAL_EPISODES, seed, frozen, clip_actions=clip_actions)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.rollout(_max_episode_steps(), policy, auto_cast_to_device=False, break_when_any_done=False)
    env.close()
    reward, done = td["next", "reward"].squeeze(-1), td["next", "done"].squeeze(-1)
    first_episode = (done.long().cumsum(-1) - done.long()) == 0  # up to and including the first done
    return (reward * first_episode).sum(-1).tolist()


def _max_episode_steps() -> int:
    env = _gym_make()
    steps = env.spec.max_episode_steps
    env.close()
    return int(steps)


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
        with _timed("update: loss forward"):
            value = objective(minibatch)
        with _timed("update: backward"):
            value.backward()
        with _timed("update: clip + Adam step"):
            clip_and_step()

    if compile_update:
        return torch.compile(update)
    return update if TIMER is None else timed_update


def train_torchrl(method: str, seed: int, steps: int, compile_update: bool = False, evaluate: bool = True,
                  clip_actions: bool = True, compile_policy: bool = False) -> dict:
    """One TorchRL PPO training; ``compile_policy`` also compiles the collector's policy forward
    (TorchRL's ``Collector(compile_policy=True)``): the SDE policy's forward with the carried noise
    draws nothing, so compiling it changes no random stream."""
    from torchrl.collectors import Collector
    from torchrl.objectives import ClipPPOLoss
    from torchrl.objectives.value import GAE

    torch.manual_seed(seed)
    probe = _gym_make()
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
    curve, iteration_ends, done_frames, start = [], [], 0, time.perf_counter()
    batches = iter(collector)
    while True:
        with _timed("collect"):
            batch = next(batches, None)
        if batch is None:
            break
        done_frames += batch.numel()
        finished = batch["next", "done"].squeeze(-1)
        curve += [[done_frames, float(r)] for r in batch["next", "episode_reward"].squeeze(-1)[finished]]
        with torch.no_grad(), _timed("GAE"):
            gae(batch)
        with _timed("update"):
            flat = batch.reshape(-1).select(*MINIBATCH_KEYS, strict=False).contiguous()  # only what the loss reads
            for _ in range(ZOO["n_epochs"]):
                for idx in torch.randperm(flat.numel()).split(ZOO["batch_size"]):
                    with _timed("update: minibatch indexing"):
                        minibatch = flat[idx]
                    step(minibatch)
        iteration_ends.append(time.perf_counter() - start)
        if TIMER is not None and len(iteration_ends) == 1:
            TIMER.clear()  # the first iteration (warm-up, compilation) is not timed
    wall = time.perf_counter() - start
    collector.shutdown()
    return {"wall_s": wall, "env_steps": done_frames, "curve": curve, "iteration_ends_s": iteration_ends,
            "eval_returns": evaluate_torchrl(policy, normalizer, 10_000 + seed, clip_actions) if evaluate else []}


# ---------------------------------------------------------------------------------------- SB3 side
_MARK = [0.0]


def _phase_mark(phase: str | None) -> None:
    """Add the time since the last mark to ``TIMER[phase]`` (SB3's phases, between its callbacks)."""
    now = time.perf_counter()
    if TIMER is not None and phase is not None:
        TIMER[phase] = TIMER.get(phase, 0.0) + now - _MARK[0]
    _MARK[0] = now


def _time_sb3_update(model) -> None:
    """Time the parts of SB3's PPO update as ``make_update``'s: the policy's forward, the clip +
    Adam step (backward is what is left of the minibatch step)."""
    policy, optimizer, clip = model.policy, model.policy.optimizer, torch.nn.utils.clip_grad_norm_
    forward, adam_step = policy.evaluate_actions, optimizer.step

    def timed_forward(*args, **kwargs):
        with _timed("update: loss forward"):
            return forward(*args, **kwargs)

    def timed_clip(*args, **kwargs):
        with _timed("update: clip + Adam step"):
            return clip(*args, **kwargs)

    def timed_step(*args, **kwargs):
        with _timed("update: clip + Adam step"):
            return adam_step(*args, **kwargs)

    policy.evaluate_actions, optimizer.step, torch.nn.utils.clip_grad_norm_ = timed_forward, timed_step, timed_clip


def train_sb3(seed: int, steps: int, use_sde: bool = True, evaluate: bool = True) -> dict:
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

    class EpisodeReturns(BaseCallback):
        def _on_rollout_start(self) -> None:  # the previous iteration's update has ended
            if self.num_timesteps:
                iteration_ends.append(time.perf_counter() - start)
                _phase_mark("update")
                if TIMER is not None and len(iteration_ends) == 1:
                    TIMER.clear()  # the first iteration is not timed
            _phase_mark(None)

        def _on_rollout_end(self) -> None:
            _phase_mark("collect")

        def _on_step(self) -> bool:
            curve.extend([self.num_timesteps, float(i["episode"]["r"])] for i in self.locals["infos"] if "episode" in i)
            return True

    env = VecNormalize(make_vec_env(_gym_make, n_envs=ZOO["n_envs"], seed=seed), gamma=ZOO["gamma"])
    model = PPO(
        "MlpPolicy", env, n_steps=ZOO["n_steps"], batch_size=ZOO["batch_size"], gamma=ZOO["gamma"],
        gae_lambda=ZOO["gae_lambda"], n_epochs=ZOO["n_epochs"], ent_coef=ZOO["ent_coef"], use_sde=use_sde,
        sde_sample_freq=ZOO["sde_sample_freq"], max_grad_norm=ZOO["max_grad_norm"], vf_coef=ZOO["vf_coef"],
        learning_rate=ZOO["learning_rate"], clip_range=ZOO["clip_range"], seed=seed, device="cpu",
        policy_kwargs={"log_std_init": ZOO["log_std_init"], "ortho_init": False, "activation_fn": torch.nn.ReLU,
                       "net_arch": {"pi": ZOO["net_arch"], "vf": ZOO["net_arch"]}},
    )
    if TIMER is not None:
        _time_sb3_update(model)
    start = time.perf_counter()
    model.learn(total_timesteps=steps, callback=EpisodeReturns())
    _phase_mark("update")  # the last iteration's update
    wall = time.perf_counter() - start
    iteration_ends.append(wall)
    if not evaluate:
        return {"wall_s": wall, "env_steps": int(model.num_timesteps), "iteration_ends_s": iteration_ends}
    eval_env = VecNormalize(make_vec_env(_gym_make, n_envs=1, seed=10_000 + seed), training=False, norm_reward=False)
    eval_env.obs_rms = env.obs_rms
    returns, _ = evaluate_policy(model, eval_env, n_eval_episodes=EVAL_EPISODES, deterministic=True,
                                 return_episode_rewards=True)
    return {"wall_s": wall, "env_steps": int(model.num_timesteps), "curve": curve, "iteration_ends_s": iteration_ends,
            "eval_returns": [float(r) for r in returns]}


# ------------------------------------------------------------------------------------------ command
def run(method: str, seed: int, steps: int, out: Path, compile_update: bool = False, clip_actions: bool = True) -> Path:
    torch.set_num_threads(1)  # one core per run: two runs side by side on a 2-core machine
    if method.startswith("sb3"):
        result = train_sb3(seed, steps, use_sde=method == "sb3")
    else:
        result = train_torchrl(method, seed, steps, compile_update, clip_actions=clip_actions)
    import torchrl

    torchrl_method = not method.startswith("sb3")
    result.update(method=method, seed=seed, compiled=compile_update and torchrl_method,
                  clipped_actions=clip_actions or not torchrl_method,  # SB3 always clips
                  env_id=ENV_ID, settings=ZOO,
                  env_steps_per_s=result["env_steps"] / result["wall_s"],
                  final_return_mean=float(np.mean(result["eval_returns"])),
                  versions={"torch": torch.__version__, "torchrl": torchrl.__version__,
                            "python": platform.python_version()})
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{method}_seed{seed}.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result))
    os.replace(tmp, path)
    return path


def _iteration_seconds(variant: str, rollouts: int) -> float:
    """Median wall time of one training iteration of ``variant``, the first iteration left out."""
    torch.set_num_threads(1)
    frames = ZOO["n_envs"] * ZOO["n_steps"]
    method, *options = variant.split("+")
    if method.startswith("sb3"):
        result = train_sb3(0, rollouts * frames, use_sde=method == "sb3", evaluate=False)
    else:
        result = train_torchrl(method, 0, rollouts * frames, compile_update="compile" in options, evaluate=False,
                               compile_policy="policy" in options)
    return float(np.median(np.diff(result["iteration_ends_s"])))


def speed(variants: list[str], rollouts: int) -> str:
    """Env steps per second of one training iteration (collect ``n_envs × n_steps``, then update).

    Each variant (``sde``, ``sde+compile``, ``sde+compile+policy``, the same for ``plain``, ``sb3``,
    ``sb3_gauss``) trains ``rollouts`` iterations on one thread in a fresh process of its own (in
    one process, whatever runs later runs slower), one variant after the other, in the order
    given (a variant may come twice); the first iteration (warm-up, compilation) is left out and
    the median of the others is reported. With ``sb3`` among them, each variant's speed is also
    given as a ratio to SB3 gSDE's (the median of its entries, if it came more than once).
    """
    import multiprocessing

    seconds = []
    for variant in variants:
        with multiprocessing.get_context("spawn").Pool(1) as pool:
            seconds.append(pool.apply(_iteration_seconds, (variant, rollouts)))
    return speed_table(variants, seconds, rollouts - 1)


def speed_table(variants: list[str], seconds: list[float], timed: int) -> str:
    """The ``speed`` table: seconds per iteration, env steps per second and, with ``sb3`` among
    the variants, the ratio to SB3 gSDE's speed (its median over its entries).

    Examples:
        >>> print(speed_table(["sb3", "sde", "sb3"], [4.0, 5.0, 6.0], 5).splitlines()[3])
        | sde | 5.00 | 1638 | 1.00 | 5 |
    """
    frames = ZOO["n_envs"] * ZOO["n_steps"]
    reference = [s for v, s in zip(variants, seconds, strict=True) if v == "sb3"]
    sb3 = float(np.median(reference)) if reference else None
    lines = ["| variant | median s / iteration | env steps / s | × SB3 gSDE's env steps / s | iterations timed |",
             "| --- | --- | --- | --- | --- |"]
    for variant, s in zip(variants, seconds, strict=True):
        ratio = f"{sb3 / s:.2f}" if sb3 else "-"
        lines.append(f"| {variant} | {s:.2f} | {frames / s:.0f} | {ratio} | {timed} |")
    return "\n".join(lines) + "\n"


def _iteration_phases(variant: str, rollouts: int) -> dict[str, float]:
    """Seconds per iteration of each phase of ``variant``'s training, the first iteration left out."""
    global TIMER
    TIMER = {}
    seconds = _iteration_seconds(variant, rollouts)
    phases = {phase: total / (rollouts - 1) for phase, total in TIMER.items()}
    TIMER = None
    return {"iteration": seconds, **phases}


def phases(variants: list[str], rollouts: int) -> str:
    """Where one iteration's time goes: collection (and pybullet's share of it), GAE and the update
    (and its parts), in seconds per iteration, each variant in a fresh process on one thread.

    SB3 computes GAE inside its collection; its "loss forward" is the policy's
    ``evaluate_actions`` (actor and critic), ours ``ClipPPOLoss``'s whole forward; a compiled
    update is timed whole. The timers themselves cost a few microseconds per call.
    """
    import multiprocessing

    table = {}
    for variant in variants:
        with multiprocessing.get_context("spawn").Pool(1) as pool:
            table[variant] = pool.apply(_iteration_phases, (variant, rollouts))
    rows = ["iteration", "collect", "collect: pybullet step", "GAE", "update", "update: minibatch indexing",
            "update: loss forward", "update: backward", "update: clip + Adam step"]
    lines = [f"| seconds per iteration | {' | '.join(variants)} |", f"| --- |{' --- |' * len(variants)}"]
    for row in rows:
        cells = [f"{table[v][row]:.2f}" if row in table[v] else "-" for v in variants]
        lines.append(f"| {row} | {' | '.join(cells)} |")
    return "\n".join(lines) + "\n"


def load_runs(folder: Path) -> dict[str, list[dict]]:
    runs: dict[str, list[dict]] = {m: [] for m in METHODS}
    for path in sorted(folder.glob("*_seed*.json")):
        data = json.loads(path.read_text())
        runs[data["method"]].append(data)
    if not any(runs.values()):
        raise SystemExit(f"bench_ppo: no <method>_seed<k>.json runs in {folder}: run `bench_ppo.py run` first")
    return runs


def report(folder: Path, out: Path) -> str:
    runs = load_runs(folder)
    names = {"plain": "TorchRL PPO, Gaussian", "sde": "TorchRL PPO, SDE (ours)", "sb3": "SB3 PPO, gSDE",
             "sb3_gauss": "SB3 PPO, Gaussian"}
    for method in ("plain", "sde"):
        if runs[method] and all(r.get("compiled") for r in runs[method]):
            names[method] += ", compiled update"
    rows, stats = [], {}
    for method in METHODS:
        if not runs[method]:
            continue
        finals = np.array([r["final_return_mean"] for r in runs[method]])
        speed = np.array([r["env_steps_per_s"] for r in runs[method]])
        stats[method] = {"final": finals.tolist(), "speed": speed.tolist(), "steps": runs[method][0]["env_steps"]}
        rows.append(f"| {names[method]} | {len(finals)} | {stats[method]['steps']:,} | {finals.mean():.0f} ± "
                    f"{finals.std(ddof=1) if len(finals) > 1 else 0:.0f} | {', '.join(f'{f:.0f}' for f in finals)} "
                    f"| {speed.mean():.0f} |")
    lines = ["| method | seeds | env steps | final deterministic return (mean ± sd over seeds) | per seed "
             "| env steps / s |", "| --- | --- | --- | --- | --- | --- |", *rows]
    if "sde" in stats and "sb3" in stats:
        ratios = {}
        for quantity in ("final", "speed"):
            ratios[quantity] = bootstrap_interval((stats["sde"][quantity], stats["sb3"][quantity]), ratio_of_means)
        stats["sde_over_sb3"] = {q: ratio._asdict() for q, ratio in ratios.items()}
        ret, spd = ratios["final"], ratios["speed"]
        lines += ["", f"SDE / SB3 gSDE: final return {ret.estimate:.2f}× [{ret.low:.2f}, {ret.high:.2f}] "
                      f"(target ≥ 0.90), env steps per second {spd.estimate:.2f}× [{spd.low:.2f}, {spd.high:.2f}] "
                      "(target ≥ 0.8); [95 % bootstrap intervals over seeds]."]
    table = "\n".join(lines) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_ppo.md").write_text(table)
    (out / "bench_ppo.json").write_text(json.dumps(stats, indent=1))
    _plot(runs, names, out / "bench_ppo.png")
    return table


def _plot(runs: dict[str, list[dict]], names: dict[str, str], path: Path) -> None:
    bin_steps = 50_000
    with saved_figure(path, figsize=(6.4, 4)) as (_, ax):
        for method, method_runs in runs.items():
            if not method_runs:
                continue
            total = max(r["env_steps"] for r in method_runs)
            curves = np.stack([binned_curve(r, bin_steps, total) for r in method_runs])
            x = (np.arange(curves.shape[1]) + 1) * bin_steps
            with warnings.catch_warnings():  # a window where no episode ended is a gap in the curve
                warnings.simplefilter("ignore", RuntimeWarning)
                mean, low, high = np.nanmean(curves, 0), np.nanmin(curves, 0), np.nanmax(curves, 0)
            ax.plot(x, mean, label=f"{names[method]} ({len(method_runs)} seeds)")
            if len(method_runs) > 1:
                ax.fill_between(x, low, high, alpha=0.2)
        ax.set_xlabel("env steps")
        ax.set_ylabel("training episode return (raw)")
        ax.set_title(f"PPO on {ENV_ID} (rl-zoo settings); band: min-max over seeds", fontsize=9)
        ax.legend()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run_p = sub.add_parser("run", help="train one method with one seed")
    run_p.add_argument("--method", choices=METHODS, required=True)
    run_p.add_argument("--seed", type=int, default=0)
    run_p.add_argument("--steps", type=int, default=500_000)
    run_p.add_argument("--out", type=Path, default=Path("docs/ppo/runs"))
    run_p.add_argument("--compile", action="store_true",
                       help="torch.compile the whole TorchRL update (loss, backward, clip, Adam)")
    run_p.add_argument("--unclipped-actions", action="store_true",
                       help="ablation: step the TorchRL env with the sampled, unclipped action")
    speed_p = sub.add_parser("speed", help="env steps per second of single iterations, one variant after another")
    speed_p.add_argument("variants", nargs="+", choices=SPEED_VARIANTS)
    speed_p.add_argument("--rollouts", type=int, default=4, help="iterations per variant (the first is not timed)")
    speed_p.add_argument("--out", type=Path, default=None, help="also write the table to this markdown file")
    phases_p = sub.add_parser("phases", help="where one iteration's time goes, per variant")
    phases_p.add_argument("variants", nargs="+", choices=SPEED_VARIANTS)
    phases_p.add_argument("--rollouts", type=int, default=3, help="iterations per variant (the first is not timed)")
    phases_p.add_argument("--out", type=Path, default=None, help="also write the table to this markdown file")
    rep_p = sub.add_parser("report", help="table and plot from a folder of runs")
    rep_p.add_argument("folder", type=Path)
    rep_p.add_argument("--out", type=Path, default=Path("docs/ppo"))
    args = parser.parse_args(argv)
    if args.command == "run":
        if args.steps <= 0:
            parser.error(f"--steps must be positive, got {args.steps}")
        if (args.compile or args.unclipped_actions) and args.method.startswith("sb3"):
            parser.error("--compile and --unclipped-actions apply to the TorchRL methods (plain, sde), not to SB3")
        path = run(args.method, args.seed, args.steps, args.out, args.compile, not args.unclipped_actions)
        data = json.loads(path.read_text())
        print(f"{args.method} seed {args.seed}: final return {data['final_return_mean']:.1f}, "
              f"{data['env_steps_per_s']:.0f} env steps/s, {data['wall_s']:.0f} s -> {path}")
    elif args.command in ("speed", "phases"):
        if args.rollouts < 2:
            parser.error(f"--rollouts must be at least 2 (the first is not timed), got {args.rollouts}")
        table = (speed if args.command == "speed" else phases)(args.variants, args.rollouts)
        sys.stdout.write(table)
        if args.out is not None:
            arguments = argv if argv is not None else sys.argv[1:]
            command = " ".join(["python -m analysis.benchmarks.bench_ppo", *arguments])
            title = "Speed of one PPO iteration" if args.command == "speed" else "Where one PPO iteration's time goes"
            args.out.write_text(f"# {title}\n\nWritten by `{command}` on {time.strftime('%Y-%m-%d')} "
                                f"({os.cpu_count()} cores; iterations 2-{args.rollouts}).\n\n{table}")
    else:
        sys.stdout.write(report(args.folder, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
