#!/bin/bash
# The runs in docs/sac/runs, one at a time on one core (torch.set_num_threads(1)), in this order.
# Budgets (the machine's CPU budget, not the zoo's): MountainCarContinuous 8,000 env steps (zoo: 50,000),
# HalfCheetahBullet 4,000 env steps with learning_starts 1,000 on both sides (zoo: 1,000,000 and 10,000).
# Usage, from the repository root: bash docs/sac/runs/sweep.sh [OUT]   (OUT defaults to docs/sac/runs)
set -euo pipefail
OUT=${1:-docs/sac/runs}
run() { python -m analysis.benchmarks.bench_sac run "$@" --out "$OUT"; }
run --env mountaincar --method sde --seed 0 --steps 8000
run --env mountaincar --method sb3 --seed 0 --steps 8000
run --env mountaincar --method sb3 --seed 1 --steps 8000
run --env mountaincar --method sde --seed 1 --steps 8000
run --env mountaincar --method sb3_gauss --seed 0 --steps 8000
run --env mountaincar --method plain --seed 0 --steps 8000
run --env halfcheetah --method sb3 --seed 0 --steps 4000 --learning-starts 1000
run --env halfcheetah --method sde --seed 0 --steps 4000 --learning-starts 1000
run --env mountaincar --method sb3 --seed 2 --steps 8000
run --env mountaincar --method sde --seed 2 --steps 8000
run --env mountaincar --method sb3_gauss --seed 1 --steps 8000
run --env mountaincar --method plain --seed 1 --steps 8000
run --env mountaincar --method sb3 --seed 3 --steps 8000
run --env mountaincar --method sde --seed 3 --steps 8000
run --env mountaincar --method sb3 --seed 4 --steps 8000
run --env mountaincar --method sde --seed 4 --steps 8000
run --env mountaincar --method sde --seed 0 --steps 8000 --loss-noise stored   # the ablation row
run --env halfcheetah --method sb3 --seed 1 --steps 4000 --learning-starts 1000
run --env halfcheetah --method sde --seed 1 --steps 4000 --learning-starts 1000
run --env mountaincar --method sde --seed 1 --steps 8000 --loss-noise stored
# The compiled update (2026-12-02; compiled autograd and inductor's min-cut partition, before compile_step) and a fresh SB3 gSDE run of each seed, so that the two speeds are
# measured on the machine as it was then, shared with other jobs (as run: SB3 seeds 0-2 beside an earlier
# build of the compiled runs, then compiled 0-2, then compiled and SB3 seeds 3 and 4 in turn). These SB3 runs
# replace the earlier ones of the same seeds; SB3 SAC on CPU does not repeat its returns exactly.
for seed in 0 1 2 3 4; do
  run --env mountaincar --method sde --seed $seed --steps 8000 --compile
  run --env mountaincar --method sb3 --seed $seed --steps 8000
done
python -m analysis.benchmarks.bench_sac report "$OUT" --out "$(dirname "$OUT")"
