#!/bin/bash
# PPO benchmark, second sweep: TorchRL PPO + SDE (LatentMLPActor, --compile) and SB3 PPO + gSDE,
# seeds 0-4 x 500k steps, then the Gaussian TorchRL PPO (compiled), seeds 0-2; two runs at a time, one core each.
# Run from an activated environment with .[bench]; results and logs go to $OUT (default: a temporary folder).
set -euo pipefail
cd "$(dirname "$0")/../../.."
export OUT="${OUT:-$(mktemp -d)}"
mkdir -p "$OUT" && echo "runs and logs in $OUT"
{ for s in 0 1 2 3 4; do echo "sde --compile $s"; echo "sb3 $s"; done; for s in 0 1 2; do echo "plain --compile $s"; done; } | \
  xargs -P 2 -L 1 bash -c 'python -m analysis.benchmarks.bench_ppo run --method $0 ${2:+$1} --seed ${2:-$1} --steps 500000 --out "$OUT/runs" > "$OUT/log_$0_${2:-$1}.txt" 2>&1'
date > "$OUT/done"
