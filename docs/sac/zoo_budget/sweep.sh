#!/bin/bash
# The runs in docs/sac/zoo_budget/runs: MountainCarContinuous at the zoo's budget (50,000 env steps), ours with
# the compiled update and policy forward against SB3 SAC + gSDE, 5 seeds each. Two lanes, one per core
# (torch.set_num_threads(1) in each run), each alternating the two methods so that both meet the same load.
# Usage, from the repository root: bash docs/sac/zoo_budget/sweep.sh [OUT]   (OUT defaults to docs/sac/zoo_budget/runs)
set -euo pipefail
OUT=${1:-docs/sac/zoo_budget/runs}
run() { python analysis/bench_sac.py run --env mountaincar --steps 50000 --out "$OUT" "$@"; }
ours() { run --method sde --compile --compile-policy --seed "$1"; }
sb3() { run --method sb3 --seed "$1"; }
(ours 0; sb3 1; ours 2; sb3 3; ours 4) &
(sb3 0; ours 1; sb3 2; ours 3; sb3 4) &
wait
python analysis/bench_sac.py report "$OUT" --out "$(dirname "$OUT")"
