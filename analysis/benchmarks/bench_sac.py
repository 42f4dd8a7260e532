"""SAC with the SDE policy on TorchRL, against Stable-Baselines3 SAC + gSDE (and both with a plain Gaussian).

Four methods, the same hyperparameters (rl-baselines3-zoo's tuned SAC settings, ``hyperparams/sac.yml``,
:data:`ZOO`), one env stepped in one process:

* ``sde``: TorchRL ``Collector`` + ``ReplayBuffer`` (``LazyTensorStorage``, uniform sampling with
  replacement) + ``SACLoss``, with the SDE policy (:func:`sde_torchrl.make_sde_actor`, tanh-squashed):
  features ``x`` from the actor's last hidden layer, *not* detached (SB3's SAC builds its gSDE
  distribution with ``learn_features=True``), the mean clipped to ``[-2, 2]`` before the squash
  (SB3's ``clip_mean=2.0``), one ``σ̂`` per matrix element (``full_std=True``), ``p`` initialised to
  ``log_std_init``; the collection noise ``ξ`` is redrawn every ``train_freq`` steps and at every
  reset (``schedule="every_n"``);
* ``plain``: the same loop with a tanh-squashed state-dependent Gaussian (TorchRL ``TanhNormal``,
  mean and log-std heads on the last hidden layer, log-std clamped to ``[-20, 2]``: SB3's SAC actor
  without gSDE);
* ``sb3``: Stable-Baselines3 ``SAC(use_sde=True)``;
* ``sb3_gauss``: the same with ``use_sde=False``.

**Which noise the actor loss uses.** The replay buffer holds the ``ξ`` each transition was
collected with, but the SAC losses (the actor loss, and the next-state action of the critic's
target) use a *fresh* standard-normal matrix, one per gradient step shared by the whole
minibatch, as SB3 does (``actor.reset_noise()`` at each gradient step, whose single
``exploration_mat`` serves every row; ``sac/sac.py``, ``common/distributions.py``). Reason: the
reparameterised SAC gradient needs ``a = μ(s) + (σ̂ ⊙ ξ) x(s)`` with ``ξ ~ N(0, I)`` independent of
``s``; a stored ``ξ`` is not: it is the noise that steered the episode into ``s`` (held for
``train_freq`` steps), so ``ξ | s`` is not standard normal and the stored noise would bias the
actor's gradient and its entropy estimate (and each transition would be scored with one and the
same ``ξ`` at every replay). :func:`sde_torchrl.trainers.sac.fresh_loss_noise` does it;
``--loss-noise stored`` keeps the buffer's ``ξ`` (the ablation row). The networks, the loss and the
gradient step are the library's (:mod:`sde_torchrl.modules.sac_actor`, :mod:`sde_torchrl.trainers.sac`),
which ``algorithm=sac`` trains with; the collection loop here is TorchRL's ``Collector``, as the
committed runs were made.

The update follows SB3's order per gradient step: critic loss and step, actor loss (with the
updated critics) and step, entropy-coefficient step (``ent_coef: auto`` only; the critic and actor
use the coefficient from before that step), Polyak update of the target critics. TorchRL's
critic loss ``Σ_k (Q_k - y)²`` is halved to SB3's ``½ Σ_k MSE`` (Adam would not see the factor).
With ``learning_starts > 0`` both sides act uniformly at random until then (SB3's default
``use_sde_at_warmup=False``; TorchRL's ``init_random_frames``).

Differences left, as the committed runs were made: ``σ̂ = expln(p)`` here, ``exp(p)`` in SB3
(equal while ``p <= 0``: each run records its largest ``p``; the library's
``SDEParams(sigma_transform="exp")`` is SB3's); SB3 counts its ``train_freq`` resampling period
over the run, our ``every_n`` restarts at each reset (``schedule="every_n_steps"`` is SB3's
counting); SB3 adds 1e-6 to the action variance and to ``1 - tanh²`` and scores ``atanh`` of the
squashed action, ours scores the exact pre-squash sample.

**The compiled update** (``run --compile``, the ``sde_compiled`` row): the whole gradient step
above (fresh noise, both losses, their backward passes, the Adam steps, the target update) goes
through ``torch.compile`` (inductor, its min-cut partitioner told to recompute boolean masks rather
than save them: :func:`recompute_boolean_masks`), as TorchRL's own SAC scripts compile theirs with
their ``compile`` option. It computes the same step (tested against the eager one with
inductor and the stored noise); the fresh noise inside it
comes from inductor's random generator, not eager PyTorch's, so a compiled run is not the eager
run of the same seed. The first steps compile, inside the timed training: the report gives the
compilation's time (the first round of gradient steps less the median round, :func:`compilation_s`)
and the speed without it, the speed a longer run tends to. ``run --compile --compile-policy`` also
compiles the collector's policy forward (TorchRL's ``Collector(compile_policy=True)``; the
``sde_compiled_policy`` row): the SDE actor's TensorDict modules, distribution and sample in one graph.

Each run writes ``<out>/<env>_<method>_seed<k>.json``: the deterministic return of 10 evaluation
episodes at the end, the training episodes' returns against env steps, env steps per
second of the whole training (collection and updates, evaluation excluded), wall clock and CPU
time, and (TorchRL) the wall and CPU seconds of each round of gradient steps. ``report`` turns
a folder of runs into a table per env and a plot; ``update-speed`` times
single gradient steps of the four methods and profiles ours.

Usage::

    python -m analysis.benchmarks.bench_sac run --env mountaincar --method sde --seed 0 --steps 8000 --out docs/sac/runs
    python -m analysis.benchmarks.bench_sac run --env mountaincar --method sde --compile --compile-policy --seed 0 \
        --out docs/sac/zoo_budget/runs
    python -m analysis.benchmarks.bench_sac report docs/sac/runs --out docs/sac
    python -m analysis.benchmarks.bench_sac update-speed --env mountaincar --profile \
        --out docs/sac/update_speed_mountaincar.md

Examples:
    >>> sorted(METHODS), sorted(ENVS)
    (['plain', 'sb3', 'sb3_gauss', 'sde'], ['halfcheetah', 'mountaincar'])
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from analysis.figures import binned_curve
from sde_torchrl.modules.sac_actor import make_sac_networks
from sde_torchrl.trainers.sac import SACUpdate, make_sac_loss
from sde_torchrl.utils.intervals import bootstrap_interval

METHODS = ("sde", "plain", "sb3", "sb3_gauss")
LOSS_NOISE = ("fresh", "stored")
EVAL_EPISODES = 10
#: The late training return averages the training episodes that ended in this last fraction of the run.
LATE_FRACTION = 0.25
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
ENVS = tuple(ZOO)
#: What the losses read of a transition (the SDE policy's noise only with gSDE).
BUFFER_KEYS = ("observation", "action", ("next", "observation"), ("next", "reward"), ("next", "done"),
               ("next", "terminated"), "sde_noise", ("next", "sde_noise"))


def _gym_make(env_id: str):
    import gymnasium as gym

    if "Bullet" in env_id:
        import pybullet_envs_gymnasium  # noqa: F401  (registers the Bullet envs)
    return gym.make(env_id)


def _env_dims(env_id: str) -> tuple[int, int, int]:
    env = _gym_make(env_id)
    dims = env.observation_space.shape[0], env.action_space.shape[0], int(env.spec.max_episode_steps)
    env.close()
    return dims


# ----------------------------------------------------------------------------------- TorchRL side
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


def make_update(loss, sde, zoo: dict, loss_noise: str = "fresh", compile_update: bool = False):
    """One SAC gradient step on a sampled minibatch, in SB3's order (:class:`sde_torchrl.trainers.sac.SACUpdate`).

    Args:
        loss: the ``SACLoss``.
        sde: the :class:`~sde_torchrl.SDEParams` (``None`` for the Gaussian).
        zoo: the env's settings.
        loss_noise: ``"fresh"`` (:func:`~sde_torchrl.trainers.sac.fresh_loss_noise`) or ``"stored"`` (the
            buffer's ``ξ``).
        compile_update: run the whole step through ``torch.compile`` (inductor, with
            :func:`recompute_boolean_masks`).

    Returns:
        ``update(batch)``.
    """
    update = SACUpdate(loss, sde, lr=zoo["learning_rate"], tau=zoo["tau"], loss_noise=loss_noise)
    return torch.compile(update.__call__, backend=inductor_recomputing_boolean_masks) if compile_update else update


def inductor_recomputing_boolean_masks(graph, example_inputs):
    """``torch.compile``'s inductor backend, its partition made under :func:`recomputing_boolean_masks`.

    The settings hold while a graph compiles, not at every call of the compiled function.
    """
    from torch._inductor.compile_fx import compile_fx

    with recomputing_boolean_masks():
        return compile_fx(graph, example_inputs)


def recomputing_boolean_masks():
    """AOTAutograd's settings that apply :func:`recompute_boolean_masks` to what compiles within them.

    The pass is not part of AOTAutograd's cache key, so its cache is off: a graph cached by a
    process without the pass is not reused.
    """
    return torch._functorch.config.patch(joint_custom_pass=recompute_boolean_masks, enable_autograd_cache=False)


def recompute_boolean_masks(joint_graph, joint_inputs):
    """AOTAutograd joint-graph pass: the backward recomputes boolean tensors instead of saving them.

    Inductor's min-cut partitioner saves the smallest tensors the backward needs; for ReLU,
    ``hardtanh``, ``clamp`` and ``min`` those are their boolean masks (1 byte each, where the
    float inputs they come from are 4). Inductor's CPU code (torch 2.13) stores a boolean tensor many
    times slower than a float one, and at the zoo's batch of 512 those stores took more of the
    compiled step than its matrix products (``docs/reproduce/sac.md``).
    Marking every boolean node ``MUST_RECOMPUTE`` (the tag of selective activation checkpointing)
    keeps the min-cut partitioner but makes it save the float values and recompute the masks,
    fused into the backward's kernels. The step computes the same values (tested against the
    eager step, compiled by inductor); only what crosses from the forward to the backward changes.

    Args:
        joint_graph: the forward-and-backward FX graph AOTAutograd is about to partition.
        joint_inputs: its example inputs (unused).

    Returns:
        ``joint_graph``, its boolean nodes tagged.

    Examples:
        >>> graph = torch.fx.symbolic_trace(lambda x: x > 0)
        >>> mask = list(graph.graph.nodes)[1]
        >>> mask.meta["val"] = torch.zeros(2, dtype=torch.bool)
        >>> recompute_boolean_masks(graph, None) is graph, mask.meta["recompute"].name
        (True, 'MUST_RECOMPUTE')
    """
    from torch.utils.checkpoint import CheckpointPolicy

    for node in joint_graph.graph.nodes:
        value = node.meta.get("val")
        if node.op == "call_function" and isinstance(value, torch.Tensor) and value.dtype == torch.bool:
            node.meta["recompute"] = CheckpointPolicy.MUST_RECOMPUTE
    return joint_graph


def make_torchrl_env(env_id: str, seed: int, primer=None):
    """The env wrapped by TorchRL, training-episode returns summed (``episode_reward``)."""
    from torchrl.envs import Compose, GymEnv, RewardSum, TransformedEnv

    if "Bullet" in env_id:
        import pybullet_envs_gymnasium  # noqa: F401
    env = TransformedEnv(GymEnv(env_id), Compose(RewardSum(in_keys=["reward"], out_keys=["episode_reward"]),
                                                 *([primer] if primer is not None else [])))
    env.set_seed(seed)
    return env


def evaluate_torchrl(policy, env_id: str, seed: int, episodes: int = EVAL_EPISODES) -> list[float]:
    """Deterministic returns (``tanh`` of the mean) of ``episodes`` envs stepped side by side, first episode each."""
    import gymnasium as gym
    from torchrl.envs import GymWrapper
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    vec = gym.vector.SyncVectorEnv([lambda: _gym_make(env_id)] * episodes,
                                   autoreset_mode=gym.vector.AutoresetMode.DISABLED)
    env = GymWrapper(vec)
    env.set_seed(seed)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.rollout(_env_dims(env_id)[2], policy, auto_cast_to_device=False, break_when_any_done=False)
    env.close()
    reward, done = td["next", "reward"].reshape(episodes, -1), td["next", "done"].reshape(episodes, -1)
    first_episode = (done.long().cumsum(-1) - done.long()) == 0  # up to and including the first done
    return (reward * first_episode).sum(-1).tolist()


def train_torchrl(method: str, env_key: str, seed: int, steps: int, eval_episodes: int = EVAL_EPISODES,
                  loss_noise: str = "fresh", overrides: dict | None = None, compile_update: bool = False,
                  compile_policy: bool = False) -> dict:
    """Train ``sde`` or ``plain`` on TorchRL; returns the run's record (see the module docstring).

    ``overrides`` replaces :data:`ZOO` entries (the tests' tiny runs); ``compile_update`` compiles
    the gradient step (:func:`make_update`), ``compile_policy`` the collector's policy forward
    (TorchRL's ``Collector(compile_policy=True)``).
    """
    from torchrl.collectors import Collector
    from torchrl.data import LazyTensorStorage, RandomSampler, ReplayBuffer

    zoo = {**ZOO[env_key], **(overrides or {})}
    torch.manual_seed(seed)
    obs_dim, _, _ = _env_dims(zoo["env_id"])
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


# ---------------------------------------------------------------------------------------- SB3 side
def train_sb3(env_key: str, seed: int, steps: int, use_sde: bool = True, eval_episodes: int = EVAL_EPISODES,
              overrides: dict | None = None) -> dict:
    """Train Stable-Baselines3 SAC with the zoo's settings, ``use_sde`` on or off.

    ``overrides`` replaces :data:`ZOO` entries, as in :func:`train_torchrl`.
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

    class EpisodeReturns(BaseCallback):
        def _on_step(self) -> bool:
            curve.extend([self.num_timesteps, float(i["episode"]["r"])] for i in self.locals["infos"] if "episode" in i)
            return True

    def make():
        return _gym_make(zoo["env_id"])

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
              "gradient_steps": int(model._n_updates), "curve": curve, "eval_returns": []}
    if eval_episodes:
        eval_env = make_vec_env(make, n_envs=1, seed=10_000 + seed)
        returns, _ = evaluate_policy(model, eval_env, n_eval_episodes=eval_episodes, deterministic=True,
                                     return_episode_rewards=True)
        result["eval_returns"] = [float(r) for r in returns]
    return result


# ------------------------------------------------------------------------------------------ command
def run(method: str, env_key: str, seed: int, steps: int, out: Path, loss_noise: str = "fresh",
        eval_episodes: int = EVAL_EPISODES, overrides: dict | None = None, compile_update: bool = False,
        compile_policy: bool = False) -> Path:
    """Train one method with one seed and write ``<out>/<env>_<method>_seed<k>.json``.

    Args:
        method: one of :data:`METHODS`.
        env_key: one of :data:`ENVS`.
        seed: the seed of the run (evaluation: ``10000 + seed``).
        steps: env steps of training.
        out: the folder of runs.
        loss_noise: ``"fresh"`` or ``"stored"`` (``sde`` only, see :func:`make_update`).
        eval_episodes: deterministic evaluation episodes at the end.
        overrides: :data:`ZOO` entries replaced on both sides (a short budget's ``learning_starts``).
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
    import stable_baselines3
    import torchrl

    result.update(method=method, env=env_key, env_id=ZOO[env_key]["env_id"], seed=seed,
                  loss_noise=loss_noise if method == "sde" else None, compiled=compile_update,
                  compiled_policy=compile_policy,
                  settings={**ZOO[env_key], **(overrides or {})}, overrides=overrides or {},
                  env_steps_per_s=result["env_steps"] / result["wall_s"],
                  env_steps_per_cpu_s=result["env_steps"] / result["cpu_s"],
                  final_return_mean=float(np.mean(result["eval_returns"])),
                  versions={"torch": torch.__version__, "torchrl": torchrl.__version__,
                            "stable_baselines3": stable_baselines3.__version__,
                            "python": platform.python_version()})
    out.mkdir(parents=True, exist_ok=True)
    suffix = "_stored_noise" if method == "sde" and loss_noise == "stored" else \
        compiled_suffix(compile_update, compile_policy)
    path = out / f"{env_key}_{method}{suffix}_seed{seed}.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result))
    os.replace(tmp, path)
    return path


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
    ``updates`` calls of :func:`make_update`'s step on minibatches sampled from a ``ReplayBuffer`` of
    1,000 random transitions. Each round times every method once; the median over ``rounds`` is
    reported (wall and CPU), so that a neighbour's load hits all methods alike. With ``profile``,
    the TorchRL SDE step's time is split by function (cProfile, cumulative); with ``compile_update``
    the compiled SDE step (:func:`make_update`) is timed too, its compilation in the warm-up round.
    """
    from stable_baselines3 import SAC
    from torchrl.data import LazyTensorStorage, RandomSampler, ReplayBuffer

    torch.set_num_threads(1)
    zoo = ZOO[env_key]
    obs_dim, action_dim, _ = _env_dims(zoo["env_id"])
    action_spec = make_torchrl_env(zoo["env_id"], 0).action_spec
    steps, methods = {}, (*METHODS, *(["sde_compiled"] if compile_update else []))
    for method in methods:
        if method.startswith("sb3"):
            model = SAC("MlpPolicy", _gym_make(zoo["env_id"]), learning_rate=zoo["learning_rate"],
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


HEADER = """# SAC + SDE (TorchRL) against SB3 SAC + gSDE

Generated by `python -m analysis.benchmarks.bench_sac report FOLDER/runs --out FOLDER` from the runs in
`runs/` beside this page.
Ours: TorchRL `Collector`, `ReplayBuffer` and `SACLoss` with `make_sde_actor(..., squash=True)` (features: the
actor's last hidden layer, not detached; mean clipped to ±2; collection noise redrawn every `train_freq` steps and
at resets; the SAC losses use a fresh noise matrix per gradient step, shared by the minibatch, as SB3) or a tanh
Gaussian; SB3: `SAC(use_sde=True)` or `SAC(use_sde=False)`. Same settings on both sides (below); final return: mean
deterministic return of the evaluation episodes at the end of each run; env steps / s: the whole training
(collection and updates), wall clock and CPU time (the machine is shared, so wall-clock speeds vary with the
neighbours' load; CPU time less so). Curves: `bench_sac.png`."""


NAMES = {"sde": "TorchRL SAC, SDE (ours)", "plain": "TorchRL SAC, Gaussian", "sb3": "SB3 SAC, gSDE",
         "sb3_gauss": "SB3 SAC, Gaussian", "sde_compiled": "TorchRL SAC, SDE (ours), compiled update",
         "plain_compiled": "TorchRL SAC, Gaussian, compiled update",
         "sde_compiled_policy": "TorchRL SAC, SDE (ours), compiled update and policy forward",
         "sde_stored": "ablation: TorchRL SAC, SDE, stored ξ in the losses"}
#: The report's rows: the methods, the compiled TorchRL methods, then the ablation.
ROWS = (*METHODS, "sde_compiled", "sde_compiled_policy", "plain_compiled", "sde_stored")


def compiled_suffix(compiled: bool, compiled_policy: bool) -> str:
    """What a run's compilation adds to its file name and its report row.

    Examples:
        >>> compiled_suffix(True, True), compiled_suffix(True, False), compiled_suffix(False, False)
        ('_compiled_policy', '_compiled', '')
    """
    return "_compiled" * compiled + "_policy" * (compiled and compiled_policy)


def load_runs(folder: Path) -> dict[str, dict[str, list[dict]]]:
    """Runs by env, then by row (``sde`` runs with the stored loss noise: the ``sde_stored`` ablation row;
    runs with the compiled update: ``<method>_compiled``, also the compiled policy: ``<method>_compiled_policy``)."""
    runs: dict[str, dict[str, list[dict]]] = {}
    for path in sorted(folder.glob("*_seed*.json")):
        data = json.loads(path.read_text())
        row = "sde_stored" if data.get("loss_noise") == "stored" else \
            data["method"] + compiled_suffix(bool(data.get("compiled")), bool(data.get("compiled_policy")))
        runs.setdefault(data["env"], {m: [] for m in ROWS})[row].append(data)
    if not runs:
        raise SystemExit(f"bench_sac: no <env>_<method>_seed<k>.json runs in {folder}: run `bench_sac.py run` first")
    return runs


def compilation_s(run: dict) -> tuple[float, float]:
    """Wall and CPU seconds a run spent compiling: its first round of gradient steps less its median round.

    Examples:
        >>> compilation_s({"update_rounds_s": [[40.5, 40.0], [0.5, 0.4], [0.6, 0.4], [0.4, 0.4]]})
        (40.0, 39.6)
    """
    rounds = np.asarray(run["update_rounds_s"], dtype=float).reshape(-1, 2)
    extra = rounds[0] - np.median(rounds[1:], axis=0)
    return round(float(extra[0]), 6), round(float(extra[1]), 6)


def _ratio_of_means(ours: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    return ours.mean(-1) / theirs.mean(-1)


def _difference_of_means(ours: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    return ours.mean(-1) - theirs.mean(-1)


def _interval(name: str, interval, unit: str = "×", target: str = "") -> str:
    return f"{name} {interval.estimate:.2f}{unit} [{interval.low:.2f}, {interval.high:.2f}]{target}"


def late_training_return(run: dict, fraction: float = LATE_FRACTION) -> float:
    """Mean return of the training episodes (exploring policy) that ended in the run's last ``fraction`` of steps."""
    points = np.asarray(run["curve"], dtype=float).reshape(-1, 2)
    late = points[points[:, 0] > (1 - fraction) * run["env_steps"], 1]
    return float(late.mean()) if len(late) else float("nan")


def _mean_sd(values: np.ndarray) -> str:
    spread = values.std(ddof=1) if len(values) > 1 else 0.0
    return f"{values.mean():.1f} ± {spread:.1f} | {', '.join(f'{v:.1f}' for v in values)}"


def _compare(ours: list[float], theirs: list[float], key: str, name: str, target: str) -> tuple[str, str, dict]:
    """Ratio of means with its interval when both means are positive, else the difference of means.

    Returns:
        The JSON key (``key`` or ``key_difference``), the sentence's part and the interval.
    """
    if np.mean(ours) > 0 and np.mean(theirs) > 0:
        ratio = bootstrap_interval((ours, theirs), _ratio_of_means)
        return key, _interval(name, ratio, target=target), ratio._asdict()
    diff = bootstrap_interval((ours, theirs), _difference_of_means)
    return f"{key}_difference", _interval(f"{name} difference (ours − SB3)", diff, unit=""), diff._asdict()


def _env_table(env_runs: dict[str, list[dict]], stats: dict) -> list[str]:
    """The table of one env's methods, then each TorchRL method against its SB3 counterpart."""
    lines = ["| method | seeds | env steps | final deterministic return (mean ± sd over seeds) | per seed "
             f"| training return, last {LATE_FRACTION:.0%} of steps (mean ± sd) | per seed "
             "| env steps / s (wall) | env steps / CPU s | wall s / run |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for method in ROWS:
        if not env_runs[method]:
            continue
        finals = np.array([r["final_return_mean"] for r in env_runs[method]])
        late = np.array([late_training_return(r) for r in env_runs[method]])
        speed = np.array([r["env_steps_per_s"] for r in env_runs[method]])
        cpu_speed = [r.get("env_steps_per_cpu_s") for r in env_runs[method]]
        wall = np.array([r["wall_s"] for r in env_runs[method]])
        stats[method] = {"final": finals.tolist(), "late": late[np.isfinite(late)].tolist(), "speed": speed.tolist(),
                         "steps": env_runs[method][0]["env_steps"], "seeds": [r["seed"] for r in env_runs[method]]}
        if "_compiled" in method:
            compiling = np.array([compilation_s(r)[0] for r in env_runs[method]])
            steps = np.array([r["env_steps"] for r in env_runs[method]])
            stats[method]["compilation_s"] = compiling.tolist()
            stats[method]["speed_without_compilation"] = (steps / (wall - compiling)).tolist()
        cpu_text = "n/a"
        if None not in cpu_speed:
            stats[method]["cpu_speed"] = cpu_speed
            cpu_text = f"{np.mean(cpu_speed):.0f}"
        lines.append(f"| {NAMES[method]} | {len(finals)} | {stats[method]['steps']:,} | {_mean_sd(finals)} | "
                     f"{_mean_sd(late)} | {speed.mean():.0f} | {cpu_text} | {wall.mean():.0f} |")
    pairs = (("sde", "sb3", "SDE / SB3 gSDE"), ("sde_compiled", "sb3", "SDE, compiled update / SB3 gSDE"),
             ("sde_compiled_policy", "sb3", "SDE, compiled update and policy forward / SB3 gSDE"),
             ("plain", "sb3_gauss", "Gaussian / SB3 Gaussian"),
             ("plain_compiled", "sb3_gauss", "Gaussian, compiled update / SB3 Gaussian"))
    for ours, theirs, label in pairs:
        if ours not in stats or theirs not in stats:
            continue
        if len(stats[ours]["final"]) < 2 or len(stats[theirs]["final"]) < 2:
            continue  # no interval from one seed
        pair, sde_pair, parts = stats.setdefault(f"{ours}_over_{theirs}", {}), ours.startswith("sde"), []
        for quantity, name in (("final", "final return"), ("late", "late training return")):
            if len(stats[ours][quantity]) > 1 and len(stats[theirs][quantity]) > 1:
                target = " (target ≥ 0.90)" if sde_pair and quantity == "final" else ""
                key, text, interval = _compare(stats[ours][quantity], stats[theirs][quantity], quantity, name, target)
                pair[key] = interval
                parts.append(text)
        spd = bootstrap_interval((stats[ours]["speed"], stats[theirs]["speed"]), _ratio_of_means)
        pair["speed"] = spd._asdict()
        parts.append(_interval("env steps per second", spd, target=" (target ≥ 0.8)" if sde_pair else ""))
        if "speed_without_compilation" in stats[ours]:
            spd = bootstrap_interval((stats[ours]["speed_without_compilation"], stats[theirs]["speed"]),
                                     _ratio_of_means)
            pair["speed_without_compilation"] = spd._asdict()
            parts.append(_interval(f"without the compilation ({np.mean(stats[ours]['compilation_s']):.0f} s "
                                   "a run)", spd))
        if "cpu_speed" in stats[ours] and "cpu_speed" in stats[theirs]:
            cpu = bootstrap_interval((stats[ours]["cpu_speed"], stats[theirs]["cpu_speed"]), _ratio_of_means)
            pair["cpu_speed"] = cpu._asdict()
            parts.append(_interval("env steps per CPU second", cpu))
        lines += ["", f"{label}: {', '.join(parts)}; [95 % bootstrap intervals over seeds]."]
    return lines


def report(folder: Path, out: Path) -> str:
    """Write ``bench_sac.md``, ``bench_sac.json`` and ``bench_sac.png`` from a folder of runs; return the page."""
    runs = load_runs(folder)
    lines, stats = [HEADER, ""], {}
    for env_key in [e for e in ENVS if e in runs]:
        env_runs = runs[env_key]
        for r in (r for method_runs in env_runs.values() for r in method_runs):
            if r["settings"] != {**ZOO[env_key], **r.get("overrides", {})}:
                raise SystemExit(f"bench_sac: a {env_key} {r['method']} run (seed {r['seed']}) has other settings than "
                                 "ZOO and its overrides: rerun it or report it apart")
        shown = {k: v for k, v in ZOO[env_key].items() if k not in ("env_id", "n_timesteps", "use_sde")}
        settings = ", ".join(f"{k}={v}" for k, v in shown.items())
        replaced = sorted({f"{k}={v}" for m in env_runs.values() for r in m for k, v in r.get("overrides", {}).items()})
        lines += [f"## {ZOO[env_key]['env_id']}", "",
                  f"Zoo settings (both sides; use_sde as the method says): {settings}; "
                  f"{'replaced on both sides for the short budget: ' + ', '.join(replaced) + '; ' if replaced else ''}"
                  f"zoo budget {ZOO[env_key]['n_timesteps']:,} env steps, "
                  f"run here: {sorted({r['env_steps'] for m in env_runs.values() for r in m})} env steps; "
                  f"{sorted({len(r['eval_returns']) for m in env_runs.values() for r in m})} deterministic evaluation "
                  "episodes at the end of each run.", ""]
        stats[env_key] = {}
        lines += _env_table(env_runs, stats[env_key])
        lines.append("")
    page = "\n".join(lines)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_sac.md").write_text(page)
    (out / "bench_sac.json").write_text(json.dumps(stats, indent=1))
    _plot(runs, out / "bench_sac.png")
    return page


def _plot(runs: dict[str, dict[str, list[dict]]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    envs = [e for e in ENVS if e in runs]
    fig, axes = plt.subplots(1, len(envs), figsize=(6.4 * len(envs), 4), squeeze=False)
    for ax, env_key in zip(axes[0], envs, strict=True):
        total = max(r["env_steps"] for method_runs in runs[env_key].values() for r in method_runs)
        bin_steps = max(1000, total // 25 // 1000 * 1000)
        for method, method_runs in runs[env_key].items():
            if not method_runs:
                continue
            curves = np.stack([binned_curve(r, bin_steps, total) for r in method_runs])
            x = (np.arange(curves.shape[1]) + 1) * bin_steps
            with warnings.catch_warnings():  # a window where no episode ended is a gap in the curve
                warnings.simplefilter("ignore", RuntimeWarning)
                mean, low, high = np.nanmean(curves, 0), np.nanmin(curves, 0), np.nanmax(curves, 0)
            # pairs: one colour (SDE and SB3 gSDE, the Gaussians), the ablation its own
            color = "C2" if method == "sde_stored" else "C1" if method.startswith(("plain", "sb3_gauss")) else "C0"
            seeds = f"{len(method_runs)} seed{'s' if len(method_runs) > 1 else ''}"
            ax.plot(x, mean, label=f"{NAMES[method]} ({seeds})", color=color,
                    linestyle="--" if method.startswith("sb3") else ":" if method == "sde_stored" else
                    "-." if "_compiled" in method else "-")
            if len(method_runs) > 1:
                ax.fill_between(x, low, high, alpha=0.12, color=color)
        ax.set_xlabel("env steps")
        ax.set_ylabel("training episode return")
        ax.set_title(f"SAC, {ZOO[env_key]['env_id']}, {total:,} env steps; band: min-max over seeds", fontsize=9)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Command line: ``run`` one training, ``report`` a folder of runs."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run_p = sub.add_parser("run", help="train one method with one seed on one env")
    run_p.add_argument("--method", choices=METHODS, required=True)
    run_p.add_argument("--env", choices=ENVS, default="mountaincar")
    run_p.add_argument("--seed", type=int, default=0)
    run_p.add_argument("--steps", type=int, default=None, help="env steps (default: the zoo's n_timesteps)")
    run_p.add_argument("--out", type=Path, default=Path("docs/sac/runs"))
    run_p.add_argument("--learning-starts", type=int, default=None,
                       help="replace the zoo's learning_starts on both sides (short budgets)")
    run_p.add_argument("--eval-episodes", type=int, default=EVAL_EPISODES, help="deterministic episodes at the end")
    run_p.add_argument("--loss-noise", choices=LOSS_NOISE, default="fresh",
                       help="SDE noise of the SAC losses: a fresh matrix per gradient step (SB3) or the stored ξ")
    run_p.add_argument("--compile", action="store_true",
                       help="torch.compile the whole TorchRL gradient step (losses, backward passes, Adam, target)")
    run_p.add_argument("--compile-policy", action="store_true",
                       help="with --compile, also compile the collector's policy (Collector(compile_policy=True))")
    speed_p = sub.add_parser("update-speed", help="ms per gradient step of each method, interleaved in one process")
    speed_p.add_argument("--env", choices=ENVS, default="mountaincar")
    speed_p.add_argument("--updates", type=int, default=100, help="gradient steps per timing")
    speed_p.add_argument("--rounds", type=int, default=3, help="timed rounds (after one warm-up round)")
    speed_p.add_argument("--profile", action="store_true", help="split the TorchRL SDE step by function")
    speed_p.add_argument("--compile", action="store_true", help="also time the compiled TorchRL SDE step")
    speed_p.add_argument("--out", type=Path, default=None, help="also write the tables to this markdown file")
    rep_p = sub.add_parser("report", help="tables and plot from a folder of runs")
    rep_p.add_argument("folder", type=Path)
    rep_p.add_argument("--out", type=Path, default=Path("docs/sac"))
    args = parser.parse_args(argv)
    import logging

    import torchrl  # noqa: F401  (sets its logger up; then quieten it: its INFO lines go to stdout)

    logging.getLogger("torchrl").setLevel(logging.WARNING)
    if args.command == "run":
        steps = ZOO[args.env]["n_timesteps"] if args.steps is None else args.steps
        if steps <= 0:
            parser.error(f"--steps must be positive, got {steps}")
        if args.eval_episodes <= 0:
            parser.error(f"--eval-episodes must be positive, got {args.eval_episodes}")
        if args.loss_noise != "fresh" and args.method != "sde":
            parser.error("--loss-noise applies to the TorchRL SDE method (sde) only")
        if args.compile and args.method.startswith("sb3"):
            parser.error("--compile applies to the TorchRL methods (sde, plain), not to SB3")
        if args.compile and args.loss_noise != "fresh":
            parser.error("--compile runs the fresh loss noise only; drop --loss-noise stored or --compile")
        if args.compile_policy and not args.compile:
            parser.error("--compile-policy goes with --compile (the update compiled too)")
        if args.learning_starts is not None and not 0 <= args.learning_starts < steps:
            parser.error(f"--learning-starts must be in [0, steps), got {args.learning_starts}")
        overrides = {} if args.learning_starts is None else {"learning_starts": args.learning_starts}
        path = run(args.method, args.env, args.seed, steps, args.out, args.loss_noise, args.eval_episodes, overrides,
                   args.compile, args.compile_policy)
        data = json.loads(path.read_text())
        print(f"{args.env} {args.method} seed {args.seed}: final return {data['final_return_mean']:.1f}, "
              f"{data['env_steps_per_s']:.0f} env steps/s, {data['wall_s']:.0f} s -> {path}")
    elif args.command == "update-speed":
        if args.updates <= 0 or args.rounds <= 0:
            parser.error(f"--updates and --rounds must be positive, got {args.updates} and {args.rounds}")
        page = update_speed(args.env, args.updates, args.rounds, args.profile, args.compile)
        if args.out is not None:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text("Generated by `python -m analysis.benchmarks.bench_sac update-speed "
                                f"--env {args.env} --updates "
                                f"{args.updates} --rounds {args.rounds}{' --profile' if args.profile else ''}"
                                f"{' --compile' if args.compile else ''}`.\n\n"
                                + page)
        sys.stdout.write(page)
    else:
        sys.stdout.write(report(args.folder, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
