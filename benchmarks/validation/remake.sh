#!/usr/bin/env bash
# The `cpu` presets' validation choices, made on the validation goals (EnvSpec.validation_split:
# train goals of a split that are a test goal of no split 0-9, so no reported goal is looked at).
#
#   benchmarks/validation/remake.sh [PART ...]     # default: every part, in this order
#   benchmarks/validation/remake.sh --dry-run ...  # print the commands only
#
# A part is done when results/validation/PART/goals.json names today's validation goals
# (benchmarks/validation/goals.py writes it last); a done part is skipped, an unfinished one goes
# on from what its work folder holds (runs/validation-remake: records, trainings from their last
# checkpoint, evaluations on today's goals), so the script resumes and a part can finish on
# another machine than the one it started on.  Each part replaces its records under
# results/validation/PART; the README or spec text that reads them is updated by hand.
#   data      split 0's fit goals (its train goals less the validation goals), paper protocol,
#             100 histories each (data/validation-fit); every part that trains makes it first
#   lr        AD at 3,000 cosine steps, 3 models per learning rate (1e-3, 3e-3, 1e-2), 4 rollouts
#             of 100 episodes on each validation goal at 1,000 / 2,000 / 3,000 steps
#             (bench_icrl_curve.py, compare_curves.py); ~1.2 h of stage time
#   rollouts  one rollout's noise against the spread between trained models, from lr's 3e-3
#             models (eval_noise.py); minutes once lr is done
#   dicp      DICP (the reference's reward loss) with its cosine over 2,000, 4,000 and 8,000
#             steps, each evaluated at its end without planning, with the reference planner,
#             gated (ours) and gated with a reward threshold of 0.99 (ours), 4 rollouts of 100
#             episodes, then dicp_convergence.py; ~4.5 h of stage time.  Its evaluations are kept in
#             results/validation/dicp_steps/step-N-MODE as each finishes, and dicp-2000, dicp-4000
#             and dicp-8000 are parts of their own (~1, ~1.4 and ~2.1 h): each fits a short stay on
#             one machine, and they run side by side
#   state-encoding  DICP with the reference's 81-cell states at 4,000 steps (seed 0, as dicp-4000
#             but --state-encoding cells), without planning and with the reference planner, then
#             state_encoding.py against dicp-4000's coordinates records: ours is kept only where it
#             is ahead by more than the spread between trained models (0.98, rollouts); ~25 min
#   main-job  the README's main job on each run's validation goals (main-job.yaml, runs 0-4) at 4
#             and at 16 rollouts per goal (the same trainings, cached), on this CPU and with the
#             AVX2 kernels and code paths (another CPU's draws), then main_job_runs.py: the runs
#             and rollouts whose verdict two CPUs share within 10 minutes; ~40 min
# One part per core: `remake.sh data`, then e.g. `remake.sh lr rollouts main-job dicp-2000` and
# `remake.sh dicp-8000` side by side, then `remake.sh dicp-4000 dicp` (the curve once all three are in).
set -euo pipefail
cd "$(dirname "$0")/../.."
dry=0
if [ "${1:-}" = "--dry-run" ]; then dry=1; shift; fi
parts=("$@")
[ ${#parts[@]} -gt 0 ] || parts=(data lr rollouts dicp state-encoding main-job)
export OMP_NUM_THREADS=1 OMP_WAIT_POLICY=PASSIVE
data=data/validation-fit
work=runs/validation-remake
out=results/validation
goals="python benchmarks/validation/goals.py"

run() {  # print (quoted as a shell reads it back), then run unless --dry-run
  printf '+'; printf ' %q' "$@"; echo
  [ "$dry" = 1 ] || "$@"
}

done_part() {  # results/validation/$1 holds a finished part made on today's goals
  $goals check "$out/$1" "${@:2}"
}

fit_data() {
  [ -f "$data/meta/info.json" ] && return
  local -a again=()
  [ -d "$data" ] && again=(--resume)  # a collection cut short goes on from its finished tasks
  run lhf collect darkroom --tasks fit --histories 100 --protocol paper --collector batched \
    --ppo-backend kernel "${again[@]}" --out "$data"
}

part_lr() {
  done_part lr && return
  fit_data
  local lr rec again
  for lr in 0.001 0.003 0.01; do
    rec="$work/lr/ad-lr$lr"
    again=()
    if [ -f "$rec/curve.json" ]; then
      if $goals check "$rec/curve.json"; then again=(--resume); else run rm -rf "$rec"; fi
    fi
    run python benchmarks/bench_icrl_curve.py --dataset "$data" --objectives ad --episodes 100 \
      --seeds 0 1 2 3 --train-seeds 0 1 2 --steps 3000 --every-steps 1000 --lr "$lr" \
      --batch-size 64 --preset paper --attention-kernel kernel --tasks validation \
      --out "$rec" --work "$work/lr/models" "${again[@]}"
  done
  run rm -rf "$out/lr"
  run mkdir -p "$out/lr"
  for lr in 0.001 0.003 0.01; do run cp -r "$work/lr/ad-lr$lr" "$out/lr/ad-lr$lr"; done
  run python benchmarks/compare_curves.py "$out/lr/ad-lr0.003" "$out/lr/ad-lr0.001" \
    "$out/lr/ad-lr0.01" --labels "lr 3e-3" "lr 1e-3" "lr 1e-2" \
    --title "AD's learning rate, validation goals" --out "$out/lr"
  run $goals write "$out/lr"
}

part_rollouts() {
  done_part rollouts && return
  part_lr
  run rm -rf "$out/rollouts"
  run python benchmarks/eval_noise.py "$out/lr/ad-lr0.003" --out "$out/rollouts"
  run $goals write "$out/rollouts"
}

dicp_steps() {  # one DICP, its cosine over $1 steps, and its 4 evaluations (kept in results/)
  local steps=$1 mode again flags model="$work/dicp/dicp-$1" evals="$out/dicp_steps"
  local -a modes=(policy ref refgated refgatedthreshold99)
  for mode in "${modes[@]}"; do
    $goals check "$evals/step-$steps-$mode/eval_results.json" || break
    [ "$mode" = "${modes[-1]}" ] && return
  done
  fit_data
  if [ ! -f "$model/model.safetensors" ]; then
    again=()
    if compgen -G "$model/checkpoint-*" >/dev/null; then again=(--resume)
    elif [ -d "$model" ]; then again=(--overwrite); fi
    run lhf train --dataset "$data" --objective dicp --preset paper --max-steps "$steps" \
      --batch-size 64 --lr 3e-3 --reward-weighting data --state-encoding coordinates \
      --seed 0 --save-steps 500 --no-progress "${again[@]}" --out "$model"
  fi
  for mode in "${modes[@]}"; do
    case $mode in
      policy) flags=() ;;
      ref) flags=(--plan) ;;
      refgated) flags=(--plan --plan-gate reward_seen) ;;
      refgatedthreshold99) flags=(--plan --plan-gate reward_seen --plan-reward-threshold 0.99) ;;
    esac
    $goals check "$evals/step-$steps-$mode/eval_results.json" && continue
    [ -d "$evals/step-$steps-$mode" ] && flags+=(--overwrite)
    run lhf evaluate --model "$model" --tasks validation --episodes 100 --rollouts 4 --seed 0 \
      --no-progress "${flags[@]}" --out "$evals/step-$steps-$mode"
  done
}

part_state_encoding() {  # the reference's cell states against ours, at dicp-4000's budget
  done_part state_encoding && return
  local mode flags model="$work/dicp/dicp-4000-cells" evals="$out/state_encoding"
  fit_data
  if [ ! -f "$model/model.safetensors" ]; then
    local -a again=()
    if compgen -G "$model/checkpoint-*" >/dev/null; then again=(--resume)
    elif [ -d "$model" ]; then again=(--overwrite); fi
    run lhf train --dataset "$data" --objective dicp --preset paper --max-steps 4000 \
      --batch-size 64 --lr 3e-3 --reward-weighting data --state-encoding cells \
      --seed 0 --save-steps 500 --no-progress "${again[@]}" --out "$model"
  fi
  for mode in policy ref; do
    flags=()
    [ "$mode" = ref ] && flags=(--plan)
    $goals check "$evals/cells-$mode/eval_results.json" && continue
    [ -d "$evals/cells-$mode" ] && flags+=(--overwrite)
    run lhf evaluate --model "$model" --tasks validation --episodes 100 --rollouts 4 --seed 0 \
      --no-progress "${flags[@]}" --out "$evals/cells-$mode"
  done
  dicp_steps 4000  # the coordinates records it is compared with (kept, or made)
  run python benchmarks/validation/state_encoding.py --evals "$out/dicp_steps/step-4000" \
    "$evals/cells" --labels coordinates cells --modes policy ref --margin 0.98 --out "$evals"
  run $goals write "$evals"
}

part_dicp() {  # the three cosine lengths (each a part of its own: dicp-2000 ...), then the curve
  done_part dicp_steps && return
  local steps
  for steps in 2000 4000 8000; do dicp_steps "$steps"; done
  run python benchmarks/dicp_convergence.py --evals "$out/dicp_steps" --out "$out/dicp_steps"
  run $goals write "$out/dicp_steps"
}

part_main_job() {  # runs 0-4 at 4 rollouts, then the same trainings (cached) rolled out 16 times
  done_part main-job --splits 0 1 2 3 4 && return
  local isa what name old
  local -a env avx2=(env LHF_HF_KERNEL_MARCH=haswell ATEN_CPU_CAPABILITY=avx2 ONEDNN_MAX_CPU_ISA=AVX2)
  local -a budgets=("quick 4" "cpu 16")  # main-job.yaml's preset and its rollouts per goal
  for isa in avx512 avx2; do
    env=()
    [ "$isa" = avx2 ] && env=("${avx2[@]}")
    for what in "${budgets[@]}"; do
      set -- $what
      run "${env[@]}" lhf reproduce benchmarks/validation/main-job.yaml --preset "$1" --jobs 2 \
        --no-progress --work "$work/main-job-$isa" --out "$work/main-job/$isa-rollouts$2"
    done
  done
  run mkdir -p "$out/main-job"
  for old in "$out"/main-job/avx*; do [ -e "$old" ] && run rm -rf "$old"; done
  for name in avx512-rollouts4 avx512-rollouts16 avx2-rollouts4 avx2-rollouts16; do
    run cp -r "$work/main-job/$name" "$out/main-job/$name"
  done
  # --run-seconds: the main job's wall per run at --jobs 2, a fresh clone on a quiet 2-core Intel
  # Xeon: 309 s for 3 runs at 4 rollouts (results/darkroom-noisy-quick-xeon at f477be0), 492 s
  # for 5 runs at 16 (BENCHMARKS.md)
  run python benchmarks/validation/main_job_runs.py "$out"/main-job/avx{512,2}-rollouts{4,16} \
    --run-seconds 4=103 16=98 --budget 600 --out "$out/main-job"
  run $goals write "$out/main-job" --splits 0 1 2 3 4
}

for part in "${parts[@]}"; do
  case $part in
    data) fit_data ;;
    lr | rollouts | dicp) "part_$part" ;;
    state-encoding) part_state_encoding ;;
    dicp-2000 | dicp-4000 | dicp-8000) dicp_steps "${part#dicp-}" ;;
    main-job) part_main_job ;;
    *) echo "unknown part '$part': data, lr, rollouts, dicp[-2000|-4000|-8000], state-encoding or main-job" >&2; exit 2 ;;
  esac
done
