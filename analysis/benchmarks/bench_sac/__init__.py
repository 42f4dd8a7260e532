"""SAC: how fast ``train.py +experiment=sac_mountaincar`` trains, against Stable-Baselines3's SAC at
the same settings.

Both sides come from the one config the experiment composes: ours is the job's own trainer (its
collector, replay buffer, checks and compiled gradient step, :mod:`sde_torchrl.trainers.offpolicy`),
SB3's ``SAC`` is built from that config's settings by
:func:`analysis.benchmarks.gsde_table.sb3.sb3_settings` (gSDE with the job's SDE explorer, its plain
Gaussian with ``explorer=gaussian``), so the two cannot drift apart. Nothing here trains a run for
the results pages: the returns come from :mod:`analysis.benchmarks.gsde_table`'s runs of the same
experiment on both sides.

``speed`` times whole rounds (``train_freq`` env steps collected, then ``gradient_steps`` gradient
steps) per variant, each in a fresh process on one thread; ``update-speed`` times single gradient
steps of the job and of SB3 in one process and splits the job's eager step by function.

Usage::

    python -m analysis.benchmarks.bench_sac speed job job+eager sb3 --rounds 30 --repeats 12 --out docs/sac/speed_job.md
    python -m analysis.benchmarks.bench_sac update-speed job job+eager job_gauss sb3 sb3_gauss --env mountaincar \
        --profile --out docs/sac/update_speed_mountaincar.md

One module per job: :mod:`.rounds` (both sides' timed rounds), :mod:`.speed` (``speed``),
:mod:`.update_speed` (``update-speed``), :mod:`.cli` (the command line); what it shares with the
PPO benchmark is in :mod:`analysis.benchmarks.common`.
"""
