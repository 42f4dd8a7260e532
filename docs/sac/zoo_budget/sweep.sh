#!/bin/bash
# The runs in docs/sac/zoo_budget/runs: MountainCarContinuous at the zoo's budget (50,000 env steps), ours against
# SB3, 5 seeds each. Two lanes, one per core (torch.set_num_threads(1) in each run), each alternating the two sides
# so that both meet the same load.
# NOISE=sde (default): ours with SDE, the compiled update and policy forward, against SB3 SAC + gSDE.
# NOISE=gauss: the plain tanh Gaussians, ours with the compiled update, against SB3 SAC without gSDE.
# ONLY=sde (or ONLY=sb3) runs one side alone, over both lanes.
# Usage, from the repository root: [NOISE=sde|gauss] [ONLY=sde|sb3] bash docs/sac/zoo_budget/sweep.sh [OUT]
# (OUT: docs/sac/zoo_budget/runs)
set -euo pipefail
OUT=${1:-docs/sac/zoo_budget/runs}
ONLY=${ONLY:-}
NOISE=${NOISE:-sde}
run() { python analysis/bench_sac.py run --env mountaincar --steps 50000 --out "$OUT" "$@"; }
case "$NOISE" in
  sde) ours() { run --method sde --compile --compile-policy --seed "$1"; }; sb3() { run --method sb3 --seed "$1"; } ;;
  gauss) ours() { run --method plain --compile --seed "$1"; }; sb3() { run --method sb3_gauss --seed "$1"; } ;;
  *) echo "sweep.sh: NOISE must be sde or gauss, got '$NOISE'" >&2; exit 2 ;;
esac
case "$ONLY" in
  "") (ours 0; sb3 1; ours 2; sb3 3; ours 4) & (sb3 0; ours 1; sb3 2; ours 3; sb3 4) & ;;
  sde | sb3) side=$([ "$ONLY" = sde ] && echo ours || echo sb3)
             ($side 0; $side 2; $side 4) & ($side 1; $side 3) & ;;
  *) echo "sweep.sh: ONLY must be sde, sb3 or empty, got '$ONLY'" >&2; exit 2 ;;
esac
wait
python analysis/bench_sac.py report "$OUT" --out "$(dirname "$OUT")"
