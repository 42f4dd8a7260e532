"""PPO on HalfCheetahBullet: how fast ``train.py +experiment=ppo_halfcheetah_bullet`` trains, against
Stable-Baselines3's PPO at the same settings.

Both sides come from the one config the experiment composes: ours is the job's own trainer
(its collector, checks and compiled update), SB3's ``PPO`` is built from that config's settings
by :func:`analysis.benchmarks.gsde_table.sb3.sb3_settings` (gSDE with the job's SDE explorer, its
plain Gaussian with ``explorer=gaussian``), so the two cannot drift apart. Nothing here trains a
run for the results pages: the returns come from :mod:`analysis.benchmarks.gsde_table`'s runs of
the same experiment on both sides.

``speed`` times single iterations per variant, each in a fresh process on one thread; ``phases``
splits an iteration into collection (pybullet's step, the policy's forward, the env's
transforms), GAE and the update.

Usage::

    python -m analysis.benchmarks.bench_ppo speed sb3 job job+eager --rollouts 4 --repeats 6 --out docs/ppo/speed.md
    python -m analysis.benchmarks.bench_ppo phases sb3 job --rollouts 4 --out docs/ppo/phases_job.md

One module per job: :mod:`.iterations` (both sides' timed iterations), :mod:`.timing` (the phase
timer, and SB3's update timed within a block), :mod:`.speed` (``speed`` and ``phases``),
:mod:`.cli` (the command line); what it shares with the SAC benchmark is in
:mod:`analysis.benchmarks.common`.
"""
