"""Benchmarks: PPO and SAC against Stable-Baselines3 (``bench_ppo``, ``bench_sac``), the batched
ball-catching env against raw pybullet (``bench_ballcatch``) and the batched toy task against a
plain loop (``bench_toy``); each runs as ``python -m analysis.benchmarks.<name>``."""
