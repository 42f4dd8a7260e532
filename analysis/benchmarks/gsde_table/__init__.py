"""``train.py``'s PPO, A2C and SAC jobs against Stable-Baselines3, trained cell by cell: the gSDE
paper's PyBullet table, and the zoo's other SAC entry the project runs.

A cell is an algorithm (PPO, A2C, SAC), an env (HalfCheetah, Ant, Hopper, Walker2D Bullet, the
paper's; or MountainCarContinuous, SAC only), a noise (SDE or plain Gaussian) and a seed. ``run``
trains each cell twice:

* ours: ``train.py +experiment=<algo>_<env>_bullet`` (``sac_mountaincar``; ``explorer=gaussian``
  for the Gaussian side), as a command, into ``<out>/ours/<cell>/``;
* SB3: ``PPO``, ``A2C`` or ``SAC`` with the settings read off the config ``train.py`` composes for
  that cell (:func:`.sb3.sb3_settings`: envs, rollout and minibatch sizes, epochs, γ, λ, clip, the
  rate and its schedule, the optimiser's eps, the gradient-norm bound, net_arch and activation,
  ``ortho_init=False`` for torch's default initialisation, ``use_sde`` and ``sde_sample_freq`` from
  our explorer's schedule, ``log_std_init``, ``VecNormalize``, sb3-contrib's
  ``TimeFeatureWrapper``), the same budget, seed and evaluation schedule, into
  ``<out>/sb3/<cell>.json``.

``--fraction F`` runs ``F`` of each experiment's budget (rl-baselines3-zoo's, which for the
PyBullet envs is the paper's: 2M env steps for A2C and PPO, 1M for SAC) on both sides; a folder
holds one fraction and one set of overrides, and refuses to mix in another. ``report`` writes the
table (:mod:`.report`) beside the paper's numbers (:mod:`.paper`).

Usage::

    python -m analysis.benchmarks.gsde_table run --fraction 0.1 --algorithms ppo --envs hopper --seeds 0-2 \\
        --out runs/gsde_table_0.1
    python -m analysis.benchmarks.gsde_table report runs/gsde_table_0.1

One module per job: :mod:`.cells` (the cells, the budget, the composed config), :mod:`.sb3` (the
SB3 settings and training), :mod:`.run` (the folder and the pool of runs), :mod:`.paper` (the
paper's table), :mod:`.report` (the page, JSON and plots), :mod:`.cli` (the command line).
"""
