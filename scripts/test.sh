#!/usr/bin/env bash
# Create or reuse .venv (the exact versions of requirements.lock), install lhf_hf with the dev,
# metaworld and hub-test extras, lint, run the tests.  Extra arguments go to pytest, e.g.
#   ./scripts/test.sh -k gridworld
# Drift check: the newest versions pyproject.toml's ranges allow, in a fresh .venv-newest
# (also LHF_NEWEST=1 ./scripts/test.sh):
#   ./scripts/test.sh --newest
set -euo pipefail
# LHF_VENV relative to where the command was run, not to the repository root
if [ -n "${LHF_VENV:-}" ]; then LHF_VENV="$(realpath -m -- "$LHF_VENV")"; export LHF_VENV; fi
cd "$(dirname "$0")/.."
if [ "${1:-}" = "--newest" ]; then
  export LHF_NEWEST=1
  shift
fi
source scripts/_venv.sh "dev,metaworld,hub-test"
python -c "import sys, importlib.metadata as m; print('[lhf] python', sys.version.split()[0], *(f'{p} {m.version(p)}' for p in ('torch', 'transformers', 'datasets', 'huggingface-hub', 'accelerate')))"
ruff check lhf_hf tests benchmarks
exec python -m pytest "$@"
