#!/bin/bash
# PPO benchmark sweep: 3 methods x 3 seeds x 500k steps, two runs side by side
cd /work/wt/ppo && . /work/venv/bin/activate && export PYTHONPATH=$PWD
for s in 0 1 2; do for m in sb3 sde plain; do echo "$m $s"; done; done | \
  xargs -P 2 -L 1 bash -c 'python -m analysis.benchmarks.bench_ppo run --method $0 --seed $1 --steps 500000 --out /work/sweeps/ppo/runs > /work/sweeps/ppo/log_$0_$1.txt 2>&1'
date > /work/sweeps/ppo/done
