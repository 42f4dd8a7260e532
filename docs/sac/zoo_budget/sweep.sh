#!/bin/bash
# The runs in results/sac/zoo_budget/runs: MountainCarContinuous at the zoo's budget (50,000 env steps), ours against
# SB3, 5 seeds each (SEEDS=n for seeds 0..n-1). Two lanes, one per core (torch.set_num_threads(1) in each
# run), each alternating the two sides so that both meet the same load.
# NOISE=sde (default): ours with SDE, the compiled update and policy forward, against SB3 SAC + gSDE.
# NOISE=gauss: the plain tanh Gaussians, ours with the compiled update, against SB3 SAC without gSDE.
# ONLY=ours (or ONLY=sb3) runs one side alone, over both lanes.
# Usage, from the repository root: [NOISE=sde|gauss] [ONLY=ours|sb3] [SEEDS=n] bash docs/sac/zoo_budget/sweep.sh [OUT]
# (OUT: results/sac/zoo_budget/runs)
set -euo pipefail
OUT=${1:-results/sac/zoo_budget/runs}
ONLY=${ONLY:-}
NOISE=${NOISE:-sde}
SEEDS=${SEEDS:-5}
run() { python -m analysis.benchmarks.bench_sac run --env mountaincar --steps 50000 --out "$OUT" "$@"; }
case "$NOISE" in
  sde) ours() { run --method sde --compile --compile-policy --seed "$1"; }; sb3() { run --method sb3 --seed "$1"; } ;;
  gauss) ours() { run --method plain --compile --seed "$1"; }; sb3() { run --method sb3_gauss --seed "$1"; } ;;
  *) echo "sweep.sh: NOISE must be sde or gauss, got '$NOISE'" >&2; exit 2 ;;
esac
# lane k runs seeds 0..SEEDS-1, ours where seed + k is even, SB3 where odd
lane() { for ((s = 0; s < SEEDS; s++)); do if (( (s + $1) % 2 == 0 )); then ours $s; else sb3 $s; fi; done; }
# one side alone: lane k runs the seeds k, k + 2, ...
alone() { for ((s = $2; s < SEEDS; s += 2)); do $1 $s; done; }
case "$ONLY" in
  "") lane 0 & lane 1 & ;;
  ours | sb3) alone "$ONLY" 0 & alone "$ONLY" 1 & ;;
  *) echo "sweep.sh: ONLY must be ours, sb3 or empty, got '$ONLY'" >&2; exit 2 ;;
esac
wait
python -m analysis.benchmarks.bench_sac report "$OUT" --out "$(dirname "$OUT")"
