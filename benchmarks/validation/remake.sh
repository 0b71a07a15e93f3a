#!/usr/bin/env bash
# The `cpu` presets' validation choices, made on the validation goals (EnvSpec.validation_split:
# train goals of split 0 that are a test goal of no split 0-9, so no reported goal is looked at).
#
#   benchmarks/validation/remake.sh [PART ...]     # default: every part, in this order
#   benchmarks/validation/remake.sh --dry-run ...  # print the commands only
#
# Parts (each writes results/validation/PART/ and is skipped once that holds its result, so the
# script resumes part by part; data and models go to data/ and runs/validation-remake/, rebuilt
# when missing: a part can run on another machine than the one before it; trainings resume from
# their last checkpoint):
#   data      split 0's fit goals (its train goals less the validation goals), paper protocol,
#             100 histories each; every other part makes it first when it is missing
#   lr        AD at 3,000 cosine steps, 3 models per learning rate (1e-3, 3e-3, 1e-2), 4 rollouts
#             of 100 episodes on each validation goal, at 1,000 / 2,000 / 3,000 steps
#             (bench_icrl_curve.py, then compare_curves.py); ~1.2 h of stage time
#   rollouts  one rollout's noise against the spread between trained models, from lr's 3e-3
#             models (eval_noise.py); minutes
#   dicp      DICP (reference reward loss) with its cosine over 2,000, 4,000 and 8,000 steps, each
#             evaluated at its end without planning, with the reference planner, gated (ours) and
#             gated with a reward threshold of 0.99 (ours), 4 rollouts of 100 episodes
#             (dicp_convergence.py); ~5 h of stage time, the longest part
# One part per core: `remake.sh data`, then `remake.sh lr rollouts` and `remake.sh dicp` side by side.
set -euo pipefail
cd "$(dirname "$0")/../.."
dry=0
if [ "${1:-}" = "--dry-run" ]; then dry=1; shift; fi
parts=("$@")
[ ${#parts[@]} -gt 0 ] || parts=(data lr rollouts dicp)
export OMP_NUM_THREADS=1 OMP_WAIT_POLICY=PASSIVE
data=data/validation-fit
work=runs/validation-remake
out=results/validation

run() {  # print (quoted as a shell reads it back), then run unless --dry-run
  printf '+'; printf ' %q' "$@"; echo
  [ "$dry" = 1 ] || "$@"
}

current() {  # FILE exists and every task list it records is today's validation goals
  [ -f "$1" ] && python - "$1" <<'PY'
import json, sys
from lhf_hf.envs import split_part
want = sorted(split_part("darkroom", "validation", 0))
def lists(x):
    if isinstance(x, dict):
        for k, v in x.items():
            yield from ([v] if k == "tasks" else lists(v))
    elif isinstance(x, list):
        for v in x:
            yield from lists(v)
found = list(lists(json.load(open(sys.argv[1]))))
sys.exit(0 if found and all(sorted(t) == want for t in found) else 1)
PY
}

fit_data() {  # split 0's fit goals: its train goals less the validation goals
  [ -f "$data/meta/info.json" ] || run lhf collect darkroom --tasks fit --histories 100 \
    --protocol paper --collector batched --ppo-backend kernel --out "$data"
}

part_lr() {
  fit_data
  local lr again
  for lr in 0.001 0.003 0.01; do
    current "$out/lr/ad-lr$lr/curve.json" && continue
    # made in the work folder (resumed from there), then copied over the earlier record
    again=()
    [ -f "$work/lr/ad-lr$lr/curve.json" ] && again=(--resume)
    run python benchmarks/bench_icrl_curve.py --dataset "$data" --objectives ad --episodes 100 \
      --seeds 0 1 2 3 --train-seeds 0 1 2 --steps 3000 --every-steps 1000 --lr "$lr" \
      --batch-size 64 --preset paper --attention-kernel kernel --tasks validation \
      --out "$work/lr/ad-lr$lr" --work "$work/lr/models" "${again[@]}"
    run rm -rf "$out/lr/ad-lr$lr"
    run mkdir -p "$out/lr"
    run cp -r "$work/lr/ad-lr$lr" "$out/lr/ad-lr$lr"
  done
  run python benchmarks/compare_curves.py "$out/lr/ad-lr0.003" "$out/lr/ad-lr0.001" \
    "$out/lr/ad-lr0.01" --labels "lr 3e-3" "lr 1e-3" "lr 1e-2" \
    --title "AD's learning rate, validation goals" --out "$out/lr"
}

part_rollouts() {
  current "$out/lr/ad-lr0.003/curve.json" || part_lr
  run python benchmarks/eval_noise.py "$out/lr/ad-lr0.003" --out "$out/rollouts"
}

part_dicp() {
  fit_data
  local steps mode evals="$work/dicp/evals"
  for steps in 2000 4000 8000; do
    local model="$work/dicp/dicp-$steps"
    local again=()
    [ -d "$model" ] && again=(--resume)
    [ -f "$model/model.safetensors" ] || run lhf train --dataset "$data" --objective dicp \
      --preset paper --max-steps "$steps" --batch-size 64 --lr 3e-3 --reward-weighting data \
      --state-encoding coordinates --seed 0 --save-steps 500 "${again[@]}" --out "$model"
    for mode in policy ref refgated refgatedthreshold99; do
      local flags=()
      case $mode in
        ref) flags=(--plan) ;;
        refgated) flags=(--plan --plan-gate reward_seen) ;;
        refgatedthreshold99) flags=(--plan --plan-gate reward_seen --plan-reward-threshold 0.99) ;;
      esac
      current "$evals/step-$steps-$mode/eval_results.json" || run lhf evaluate --model "$model" \
        --tasks validation --episodes 100 --rollouts 4 --seed 0 "${flags[@]}" \
        --out "$evals/step-$steps-$mode"
    done
  done
  run python benchmarks/dicp_convergence.py --evals "$evals" --out "$out/dicp_steps"
}

for part in "${parts[@]}"; do
  case $part in
    data) fit_data ;;
    lr | rollouts | dicp) "part_$part" ;;
    *) echo "unknown part '$part': data, lr, rollouts or dicp" >&2; exit 2 ;;
  esac
done
