"""PPO on HalfCheetahBullet: TorchRL with a plain Gaussian or the SDE policy, against SB3 PPO + gSDE.

Three methods, the same hyperparameters (rl-baselines3-zoo's tuned PPO + gSDE settings for
``HalfCheetahBulletEnv-v0``, :data:`.build.ZOO`), the same observation and reward normalisation rule
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

    python -m analysis.benchmarks.bench_ppo run --method sde --seed 0 --steps 500000 --out results/ppo/runs
    python -m analysis.benchmarks.bench_ppo report results/ppo/runs --out docs/ppo
    python -m analysis.benchmarks.bench_ppo phases sb3 sde+compile sde --rollouts 4 --out docs/ppo/phases.md

One module per job: :mod:`.build` (the settings, the env, the policies), :mod:`.timing` (the
phase timer, and SB3's update timed within a block), :mod:`.train` (both training loops and a
run's record), :mod:`.speed` (``speed`` and ``phases``), :mod:`.report` (the table and the plot),
:mod:`.cli` (the command line); what it shares with the SAC benchmark is in
:mod:`analysis.benchmarks.common`.
"""
