#!/usr/bin/env bash
# AD, DPT and DICP on the collected Darkroom dataset (81 tasks x 100 SB3 PPO histories x 1,000 steps),
# without and with the LHF selection (linear, lambda 1), then in-context evaluation on the 8 unseen
# goals of split 0 for 100 episodes (DICP with and without planning) and the comparison table.
# A CPU budget (2 cores): paper-size models, 1,500 steps at batch 64 and lr 3e-3, vs the paper's
# 50,000 steps at batch 512 and lr 1e-2 on a GPU.  Two training queues run side by side, one thread each.
#   results/darkroom_models/run.sh            (needs data/darkroom and sel/darkroom-lhf)
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=results/darkroom_models
STEPS=${STEPS:-1500}
export OMP_NUM_THREADS=1
train() {  # objective selection-flag name
  lhf train --dataset data/darkroom --objective "$1" $2 --out "runs/darkroom-$3" --preset paper \
    --max-steps "$STEPS" --batch-size 64 --lr 3e-3 --logging-steps 100 --save-steps 500 --overwrite \
    > "runs/darkroom-$3.log" 2>&1
}
mkdir -p runs
( train ad "" ad; train ad "--selection sel/darkroom-lhf" ad-lhf; train dpt "" dpt; train dpt "--selection sel/darkroom-lhf" dpt-lhf ) &
( train dicp "" dicp; train dicp "--selection sel/darkroom-lhf" dicp-lhf ) &
wait
for m in ad ad-lhf dpt dpt-lhf dicp dicp-lhf; do
  lhf evaluate --model "runs/darkroom-$m" --episodes 100 --out "$OUT/eval/$m" > "runs/eval-$m.log" 2>&1 &
done
wait
for m in dicp dicp-lhf; do
  lhf evaluate --model "runs/darkroom-$m" --episodes 100 --plan --out "$OUT/eval/$m-plan" > "runs/eval-$m-plan.log" 2>&1 &
done
wait
lhf compare --baseline $OUT/eval/{ad,dpt,dicp,dicp-plan} --lhf $OUT/eval/{ad-lhf,dpt-lhf,dicp-lhf,dicp-lhf-plan} --out $OUT/compare
for m in ad ad-lhf dpt dpt-lhf dicp dicp-lhf; do cp "runs/darkroom-$m/train_config.json" "$OUT/train_config-$m.json"; cp "runs/darkroom-$m/training_loss.png" "$OUT/training_loss-$m.png"; done
