"""How long one SAC gradient step takes (``update-speed``): the job's own step and SB3's, built
from the one config an experiment composes, timed in one process with the variants interleaved,
and the job's eager step split by function (cProfile)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
import torch

from analysis.benchmarks.bench_sac.rounds import job_config
from analysis.benchmarks.gsde_table.sb3 import model_from_config

#: The experiments ``--env`` picks.
EXPERIMENTS = {"mountaincar": "sac_mountaincar", "halfcheetah": "sac_halfcheetah_bullet"}
#: Each variant's overrides of the experiment: ``job`` as shipped (compiled losses, fused Adam),
#: ``job+eager`` with ``algorithm.compile=false``, ``job_gauss`` its plain Gaussian; SB3's SAC
#: with gSDE (``sb3``) and without (``sb3_gauss``) at the same settings.
VARIANTS = {"job": (), "job+eager": ("algorithm.compile=false",), "job_gauss": ("explorer=gaussian",),
            "sb3": (), "sb3_gauss": ("explorer=gaussian",)}
#: Each variant's SB3 counterpart, against whose CPU time it is set.
COUNTERPART = {"job": "sb3", "job+eager": "sb3", "job_gauss": "sb3_gauss", "sb3": "sb3", "sb3_gauss": "sb3_gauss"}
#: Transitions collected with uniform random actions before the timed steps sample from them.
FILL_STEPS = 1000
#: (file, function) whose cumulative time splits the job's eager gradient step (``--profile``).
PROFILE_PARTS = {
    "critic loss forward (SACLoss.qvalue_v2_loss)": ("objectives/sac.py", "qvalue_v2_loss"),
    "actor loss forward (SACLoss.actor_loss)": ("objectives/sac.py", "actor_loss"),
    "backward passes": ("~", "run_backward"),
    "Adam steps": ("optim/adam.py", "step"),
    "target update (SoftUpdate.step)": ("objectives/utils.py", "step"),
    "replay buffer sample": ("replay_buffers/base.py", "sample"),
    "fresh loss noise": ("objectives/sac.py", "fresh_loss_noise"),
}


def _fill_overrides(experiment: str) -> tuple[str, ...]:
    """Overrides under which the job's first update collects :data:`FILL_STEPS` (rounded up to
    whole rounds) with uniform random actions and takes no gradient step (SB3: ``learning_starts``)."""
    train_freq = job_config(experiment=experiment).algorithm.train_freq
    rounds = math.ceil(FILL_STEPS / train_freq)
    return (f"algorithm.learning_starts={rounds * train_freq}", f"algorithm.rounds_per_update={rounds}", "updates=2",
            "eval_episodes=1")


def job_steps(experiment: str, overrides: tuple[str, ...], updates: int) -> Callable[[], None]:
    """``updates`` gradient steps of the job's own trainer, each on a minibatch sampled from its
    replay buffer (filled first by :func:`_fill_overrides`)."""
    from sde_torchrl.config.build_sac import build_sac_trainer

    trainer = build_sac_trainer(job_config((*_fill_overrides(experiment), *overrides), experiment))
    trainer.update(0)

    def steps() -> None:
        for _ in range(updates):
            trainer.update_step(trainer.buffer.sample())

    return steps


def sb3_steps(experiment: str, overrides: tuple[str, ...], updates: int) -> Callable[[], None]:
    """``updates`` gradient steps of SB3's SAC at the job's settings (``model.train``) on a buffer
    filled as the job's."""
    conf = job_config((*_fill_overrides(experiment), *overrides), experiment)
    settings, model, _ = model_from_config(conf, "bench_sac")
    model.learn(settings["kwargs"]["learning_starts"])  # collection only: fills the buffer, sets up the logger
    return lambda: model.train(updates, settings["kwargs"]["batch_size"])


def update_speed(env: str, updates: int, rounds: int, variants: list[str], profile: bool = False) -> str:
    """Milliseconds per gradient step of each variant (:data:`VARIANTS`), timed in one process on
    one thread, the variants interleaved.

    Each round times every variant once; the median over ``rounds`` is reported (wall and CPU), so
    that a neighbour's load hits all variants alike; a first round warms up (and compiles). With
    ``profile``, the job's eager step (``job+eager``) is split by function (cProfile, cumulative).
    """
    torch.set_num_threads(1)
    experiment = EXPERIMENTS[env]
    steps = {v: (sb3_steps if v.startswith("sb3") else job_steps)(experiment, VARIANTS[v], updates) for v in variants}
    wall: dict[str, list[float]] = {v: [] for v in variants}
    cpu: dict[str, list[float]] = {v: [] for v in variants}
    for _ in range(rounds + 1):
        for variant, step in steps.items():
            start, cpu_start = time.perf_counter(), time.process_time()
            step()
            wall[variant].append(1e3 * (time.perf_counter() - start) / updates)
            cpu[variant].append(1e3 * (time.process_time() - cpu_start) / updates)
    conf = job_config(experiment=experiment)
    lines = [f"`+experiment={experiment}` ({conf.env.id}): batch {conf.algorithm.batch_size}, hidden "
             f"{list(conf.actor.hidden)}, {updates} gradient steps × {rounds} rounds (median; a first round not "
             "timed)", "",
             "| variant | ms / gradient step (wall) | ms / gradient step (CPU) | CPU time ÷ SB3 counterpart's |",
             "| --- | --- | --- | --- |"]
    median = {v: (float(np.median(wall[v][1:])), float(np.median(cpu[v][1:]))) for v in variants}
    for variant in variants:
        counterpart = median.get(COUNTERPART[variant])
        ratio = f"{median[variant][1] / counterpart[1]:.2f}" if counterpart else "–"
        lines.append(f"| {variant} | {median[variant][0]:.1f} | {median[variant][1]:.1f} | {ratio} |")
    if profile:
        lines += ["", *profile_lines(job_steps(experiment, VARIANTS["job+eager"], updates), updates)]
    return "\n".join(lines) + "\n"


def profile_lines(steps: Callable[[], None], updates: int) -> list[str]:
    """The share of each of :data:`PROFILE_PARTS` in ``steps()`` (cProfile, cumulative), as a table."""
    import cProfile
    import pstats

    profiler = cProfile.Profile()
    profiler.runcall(steps)
    stats = pstats.Stats(profiler).stats
    total = max(entry[3] for entry in stats.values())
    lines = [f"job+eager: share of a gradient step (cProfile, cumulative, {updates} steps)", "",
             "| part | share |", "| --- | --- |"]
    for label, (where, name) in PROFILE_PARTS.items():
        cumulative = sum(entry[3] for (path, _, func), entry in stats.items()
                         if where in path and (func == name or f"'{name}'" in func))
        lines.append(f"| {label} | {cumulative / total:.0%} |")
    return lines
