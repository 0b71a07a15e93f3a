#!/usr/bin/env bash
# Run an experiment spec on a machine with a GPU and many cores, in one call, and pack what comes
# back: trainings use the GPU (Trainer takes CUDA when torch sees it), evaluations one core each.
#
#   SPEC=benchmarks/gpu/darkroom-main-dicp-long.yaml PRESET=cpu LIMIT=540 JOBS=16 OUT=/tmp/out \
#     benchmarks/gpu/run_spec.sh
#
# The machine's own python3 and packages are used; locked versions it lacks (datasets, transformers,
# gymnasium, SB3, ...) travel as wheels in .whl/ (pip download --no-deps of requirements.lock's pins
# for that python) and are installed into /tmp/site first.  The reproduction gets LIMIT seconds; on
# timeout the finished evaluations are still exported (`--export-stages`, to `lhf reproduce
# --import-stages` elsewhere), and the stage logs, the export and the report are packed into OUT.
set -u
SPEC=${SPEC:?a spec yaml}; PRESET=${PRESET:-cpu}; JOBS=${JOBS:-$(nproc)}; LIMIT=${LIMIT:-540}
PY=${PY:-python3}; OUT=${OUT:?a folder for what comes back}; WORK=${WORK:-/tmp/lhf-work}
mkdir -p "$OUT"
t0=$(date +%s)
if [ -d .whl ]; then
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 3
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD
fi
export PYTHONUNBUFFERED=1 HF_HUB_OFFLINE=1
{ $PY -c "import torch, transformers, datasets; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), 'transformers', transformers.__version__, 'datasets', datasets.__version__)"
  nproc; nvidia-smi --query-gpu=name --format=csv,noheader 2>/dev/null; } 2>&1 | tee "$OUT/env.txt"
left=$(( LIMIT - ($(date +%s) - t0) ))
timeout "$left" $PY -m lhf_hf reproduce "$SPEC" --preset "$PRESET" --jobs "$JOBS" --work "$WORK" \
  --out /tmp/lhf-report > "$OUT/reproduce.log" 2>&1
echo "[run_spec] reproduce rc=$? after $(( $(date +%s) - t0 )) s"
$PY -m lhf_hf reproduce "$SPEC" --preset "$PRESET" --work "$WORK" --export-stages /tmp/lhf-export \
  > "$OUT/export.log" 2>&1
(cd "$WORK" && find . \( -name stage.json -o -name stage.record.json -o -name stage.log \) -size -4M \
  | tar czf "$OUT/stagelogs.tgz" -T -)
[ -d /tmp/lhf-export ] && tar czf "$OUT/export.tgz" -C /tmp lhf-export
[ -d /tmp/lhf-report ] && tar czf "$OUT/report.tgz" -C /tmp lhf-report
tr '\r' '\n' < "$OUT/reproduce.log" | grep -a -E "^\[|Error|Traceback" | tail -40
echo "[run_spec] total $(( $(date +%s) - t0 )) s"
