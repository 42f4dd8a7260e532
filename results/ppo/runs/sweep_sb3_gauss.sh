#!/bin/bash
# SB3 PPO without gSDE on the zoo settings: seeds 0 and 1 side by side
cd /work/wt/ppo && . /work/venv/bin/activate && export PYTHONPATH=$PWD
for s in 0 1; do python -m analysis.benchmarks.bench_ppo run --method sb3_gauss --seed $s --steps 500000 --out /work/sweeps/ppo/runs > /work/sweeps/ppo/log_sb3_gauss_$s.txt 2>&1 & done; wait
date > /work/sweeps/ppo/done_gauss
