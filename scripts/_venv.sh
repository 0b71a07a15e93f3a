# Sourced by demo.sh / test.sh: create or reuse .venv and install lhf_hf with the given extras.
# Re-installs only when pyproject.toml changed since the last install (a stamp file remembers).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${LHF_VENV:-$ROOT/.venv}"
PYTHON="${PYTHON:-python3}"
extras="$1"
if [ ! -x "$VENV/bin/python" ]; then
  echo "[lhf] creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
stamp="$VENV/.lhf-installed-$extras"
if [ ! -f "$stamp" ] || [ "$ROOT/pyproject.toml" -nt "$stamp" ]; then
  echo "[lhf] installing lhf_hf[$extras] into $VENV (torch is pinned to the 2.13.0 CPU wheel)"
  "$VENV/bin/python" -m pip install --quiet --upgrade pip
  "$VENV/bin/python" -m pip install --quiet -e "$ROOT[$extras]"
  touch "$stamp"
fi
export PATH="$VENV/bin:$PATH"
# Headless MuJoCo: never try to open a window.
export MUJOCO_GL="${MUJOCO_GL:-disable}"
