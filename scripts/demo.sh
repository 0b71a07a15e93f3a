#!/usr/bin/env bash
# The main job on the embedded default: a tour of the environments with an oracle rollout per env,
# then a quick Darkroom end to end: a small collection with its card and plot, LHF filtering, AD and
# DICP trained with and without LHF (lightweight models, a few hundred steps), in-context evaluation
# on the 8 unseen goals and the comparison table.  Local folders stand in for the hub.
# (The paper-scale reproduction is `lhf reproduce`, a later issue.)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/_venv.sh "metaworld"
echo "[lhf] environments"
lhf envs
echo
echo "[lhf] oracle on the test tasks of split 0 (gridworlds: exact oracle; Meta-World: scripted, goal revealed)"
lhf envs --oracle --split-seed 0 --metaworld-tasks 2
echo
echo "[lhf] a small SB3 Darkroom collection (4 tasks x 20 histories x 600 transitions, noisy protocol)"
lhf collect darkroom --out data/demo-darkroom-sb3 --tasks 10,20,30,50 --histories 20 --steps 600 \
  --protocol noisy --workers 2 --overwrite
echo
echo "[lhf] the 73 train goals of split 0 with the batched PPO collector (20 histories x 1,000 transitions, noisy)"
lhf collect darkroom --out data/demo-darkroom --tasks train --histories 20 --steps 1000 \
  --protocol noisy --collector batched --overwrite
echo
echo "[lhf] LHF filtering of that dataset (linear, lambda = 1), materialised as a new dataset"
lhf filter data/demo-darkroom --out data/demo-darkroom-selection --materialize data/demo-darkroom-lhf --overwrite
echo
echo "[lhf] AD and DICP, without and with the LHF selection (lightweight preset, 300 steps each)"
for obj in ad dicp; do
  lhf train --dataset data/demo-darkroom --objective "$obj" --out "runs/demo-$obj" --preset lightweight \
    --max-steps 300 --batch-size 32 --lr 3e-3 --logging-steps 100 --save-steps 300 --overwrite
  lhf train --dataset data/demo-darkroom --selection data/demo-darkroom-selection --objective "$obj" \
    --out "runs/demo-$obj-lhf" --preset lightweight --max-steps 300 --batch-size 32 --lr 3e-3 \
    --logging-steps 100 --save-steps 300 --overwrite
done
echo
echo "[lhf] in-context evaluation on the 8 unseen goals, 20 episodes (DICP with planning)"
lhf evaluate --model runs/demo-ad --episodes 20 --out runs/demo-eval/ad
lhf evaluate --model runs/demo-ad-lhf --episodes 20 --out runs/demo-eval/ad-lhf
lhf evaluate --model runs/demo-dicp --episodes 20 --plan --out runs/demo-eval/dicp
lhf evaluate --model runs/demo-dicp-lhf --episodes 20 --plan --out runs/demo-eval/dicp-lhf
echo
lhf compare --baseline runs/demo-eval/ad runs/demo-eval/dicp --lhf runs/demo-eval/ad-lhf runs/demo-eval/dicp-lhf \
  --out runs/demo-eval/compare
echo
echo "[lhf] done: data/demo-darkroom{,-sb3}/README.md (cards), data/demo-darkroom/meta/learning_curve.png,"
echo "      data/demo-darkroom-selection/selection.png (what LHF kept), data/demo-darkroom-lhf (filtered dataset),"
echo "      runs/demo-*/README.md (model cards), runs/demo-eval/*/eval_curve.png, runs/demo-eval/compare/compare.png"
echo "      (one run of 300 steps: the numbers show the pipeline, not the paper's effect)"
