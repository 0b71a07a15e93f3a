#!/usr/bin/env bash
# The main job on the embedded default: a tour of the environments with an oracle rollout per env.
# then a small Darkroom collection with its card and plot, filtered with LHF.
# (Later issues grow this into the quick end-to-end Darkroom reproduction.)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/_venv.sh "metaworld"
echo "[lhf] environments"
lhf envs
echo
echo "[lhf] oracle on the test tasks of split 0 (gridworlds: exact oracle; Meta-World: scripted, goal revealed)"
lhf envs --oracle --split-seed 0 --metaworld-tasks 2
echo
echo "[lhf] a small Darkroom collection (4 tasks x 20 histories x 600 transitions, noisy protocol)"
lhf collect darkroom --out data/demo-darkroom --tasks 10,20,30,50 --histories 20 --steps 600 \
  --protocol noisy --workers 2 --overwrite
echo
echo "[lhf] LHF filtering of that dataset (linear, lambda = 1), materialised as a new dataset"
lhf filter data/demo-darkroom --out data/demo-darkroom-selection --materialize data/demo-darkroom-lhf --overwrite
echo "[lhf] done: data/demo-darkroom/README.md (card), data/demo-darkroom/meta/learning_curve.png,"
echo "      data/demo-darkroom-selection/selection.png (what LHF kept), data/demo-darkroom-lhf (filtered dataset)"
