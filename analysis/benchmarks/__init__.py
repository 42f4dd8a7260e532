"""Benchmarks: ``train.py``'s PPO, A2C and SAC jobs against Stable-Baselines3 configured from the same
config (``gsde_table``), the PPO job's iterations (``bench_ppo``) and the SAC job's rounds and
gradient steps (``bench_sac``) timed against SB3's, where a whole training's time goes on both sides
(``time_split``), the batched ball-catching env against raw pybullet (``bench_ballcatch``) and the
batched toy task against a plain loop (``bench_toy``); each runs as ``python -m analysis.benchmarks.<name>``."""
