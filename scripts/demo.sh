#!/usr/bin/env bash
# The main job on the embedded default: a tour of the environments with an oracle rollout per env.
# (Later issues grow this into the quick end-to-end Darkroom reproduction.)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/_venv.sh "metaworld"
echo "[lhf] environments"
lhf envs
echo
echo "[lhf] oracle on the test tasks of split 0 (gridworlds: exact oracle; Meta-World: scripted, goal revealed)"
lhf envs --oracle --split-seed 0 --metaworld-tasks 2
