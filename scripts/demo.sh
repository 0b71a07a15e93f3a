#!/usr/bin/env bash
# The main job on the embedded default (local folders stand in for the hub): the environment
# registry, then `lhf reproduce darkroom-noisy --preset quick --jobs 2`: the paper's noisy-data
# experiment on Darkroom (30% of the histories from a random policy), lightweight AD, 5 runs, end to end
# (batched PPO collection of the train goals, LHF filtering, AD trained with and without LHF,
# in-context evaluation on the unseen goals, the comparison), ending in a report of E with its error
# bar beside the paper's number; two stages at a time, one per core.  Every stage is cached under
# runs/reproduce: a second run only rewrites the report.  Extra arguments go to `lhf reproduce`
# (e.g. ./scripts/demo.sh --runs 3).
set -euo pipefail
# LHF_VENV relative to where the command was run, not to the repository root
if [ -n "${LHF_VENV:-}" ]; then LHF_VENV="$(realpath -m -- "$LHF_VENV")"; export LHF_VENV; fi
cd "$(dirname "$0")/.."
source scripts/_venv.sh "dev,metaworld,hub-test"
echo "[lhf] environments"
lhf envs
echo
out=runs/darkroom-noisy-quick
if [ -f "$out/report.md" ] && [ ! -f "$out/.lhf_output.json" ]; then
  # this script's own report from a version without output markers: kept aside, not replaced
  old="$out.unmarked-$(date +%Y%m%d-%H%M%S)"
  mv "$out" "$old" && echo "[lhf] an earlier report (no output marker) moved to $old"
fi
lhf reproduce darkroom-noisy --preset quick --jobs 2 --out "$out" "$@"
echo
sed -n '/^## Relative enhancement/,/^## Absolute/p' "$out/report.md" | head -n -1
echo "[lhf] report: $out/report.md (curves: $out/darkroom/lhf/compare.png; stage cache: runs/reproduce)"
