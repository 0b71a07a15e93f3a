#!/usr/bin/env bash
# Issue 56: one DICP trained far past the cpu presets' 4,000 steps, its snapshots evaluated on the
# validation goals (results/validation/dicp_long/README.md).
#
#   benchmarks/validation/dicp_long.sh [STEPS [SEED]]   # default 20000 0; ~1.7 h on 2 free cores
#
# The data is remake.sh's (split 0's fit goals, paper protocol, 100 histories each); the model is
# remake.sh's dicp-N model (the reference's reward loss, coordinates, lr 3e-3, batch 64) with its
# cosine over STEPS and training seed SEED (records: results/validation/dicp_long for seed 0,
# dicp_long-seedSEED for another).  The trainer keeps its newest 2 checkpoints, so a watcher copies
# checkpoint-N at the log-spaced N to snap-N as each appears; every snapshot, then the final
# model, is evaluated without planning (policy) and with the reference planner (ref), 4 rollouts
# of 100 episodes per validation goal, the final model also gated (refgated, ours) and with the
# true dynamics (reforacle).  Then dicp_convergence.py draws the curve.  An evaluation already
# in place is kept, so a second call finishes what the first left (a cut-short training starts
# over: its checkpoints are not resumed here).
set -euo pipefail
cd "$(dirname "$0")/../.."
steps="${1:-20000}"
seed="${2:-0}"
export OMP_NUM_THREADS=1 OMP_WAIT_POLICY=PASSIVE
data=data/validation-fit
w="runs/dicp-long-$steps-seed$seed"
ev="$w/eval"
out=results/validation/dicp_long
[ "$seed" = 0 ] || out="$out-seed$seed"
snaps=(2000 4000 8000 12000 16000)
mkdir -p "$ev"
[ -f "$data/meta/info.json" ] || benchmarks/validation/remake.sh data  # its data, made its way

copy_snapshots() {  # until the final model is written
  while [ ! -f "$w/model/model.safetensors" ]; do
    for n in "${snaps[@]}"; do
      c="$w/model/checkpoint-$n"
      if [ -d "$c" ] && [ ! -d "$w/snap-$n" ]; then
        sleep 5  # the trainer writes the folder's files one by one
        cp -r "$c" "$w/snap-$n.tmp" && mv "$w/snap-$n.tmp" "$w/snap-$n"
      fi
    done
    sleep 15
  done
}

ev1() {  # MODEL STEP MODE [FLAGS...]
  local m=$1 s=$2 mode=$3
  shift 3
  [ -f "$ev/step-$s-$mode/eval_results.json" ] && return
  lhf evaluate --model "$m" --tasks validation --episodes 100 --rollouts 4 --seed 0 \
    --no-progress "$@" --overwrite --out "$ev/step-$s-$mode"
}

if [ ! -f "$w/model/model.safetensors" ]; then
  copy_snapshots &
  watcher=$!
  trap 'kill "$watcher" 2>/dev/null || true' EXIT  # a failed training leaves no watcher behind
  lhf train --dataset "$data" --objective dicp --preset paper --max-steps "$steps" \
    --batch-size 64 --lr 3e-3 --reward-weighting data --state-encoding coordinates --seed "$seed" \
    --save-steps 1000 --no-progress --overwrite --out "$w/model" > "$w/train.log" 2>&1
  wait
fi
for n in "${snaps[@]}"; do
  [ -d "$w/snap-$n" ] || continue
  ev1 "$w/snap-$n" "$n" policy
  ev1 "$w/snap-$n" "$n" ref --plan
done
ev1 "$w/model" "$steps" policy
ev1 "$w/model" "$steps" ref --plan
ev1 "$w/model" "$steps" refgated --plan --plan-gate reward_seen
ev1 "$w/model" "$steps" reforacle --plan --plan-dynamics oracle
mkdir -p "$out"
for d in "$ev"/step-*; do
  rm -rf "$out/$(basename "$d")"
  cp -r "$d" "$out/"
done
python benchmarks/dicp_convergence.py --evals "$out" --train-log "$w/train.log" --out "$out"
