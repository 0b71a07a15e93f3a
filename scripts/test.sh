#!/usr/bin/env bash
# Create or reuse .venv, install lhf_hf with the dev, metaworld and hub-test extras, run the tests.
# Extra arguments go to pytest, e.g.  ./scripts/test.sh -k gridworld
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/_venv.sh "dev,metaworld,hub-test"
ruff check lhf_hf tests benchmarks
exec python -m pytest "$@"
