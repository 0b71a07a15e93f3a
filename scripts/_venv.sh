# Sourced by demo.sh / test.sh: create or reuse a venv and install lhf_hf with the given extras.
#
#   source scripts/_venv.sh EXTRAS          .venv, from requirements.lock (the exact tested versions)
#   LHF_NEWEST=1 source scripts/_venv.sh    .venv-newest, built afresh with the newest versions that
#                                           pyproject.toml's ranges allow (the drift check)
#
# A venv is reused only when its stamp (written after a complete install) matches the hash of
# pyproject.toml, requirements.lock and the Python it was made with: a lock or pyproject change, an
# interrupted install or a venv whose packages no longer import gets a fresh venv, never a patched one.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PYTHON="${PYTHON:-python3}"
LOCK="$ROOT/requirements.lock"
extras="$1"
newest="${LHF_NEWEST:-0}"
if [ "$newest" = 1 ]; then
  VENV="${LHF_VENV:-$ROOT/.venv-newest}"
else
  VENV="${LHF_VENV:-$ROOT/.venv}"
fi
STAMP="$VENV/.lhf-install"

_lhf_fresh_venv() {
  # Remove only what is recognisably a venv (or nothing at all): LHF_VENV may name any folder.
  if [ -e "$VENV" ]; then
    if [ -f "$VENV/pyvenv.cfg" ] || [ -z "$(ls -A "$VENV")" ]; then
      rm -rf "$VENV"
    else
      echo "[lhf] $VENV exists and is not a venv (no pyvenv.cfg): refusing to replace it" >&2
      return 1
    fi
  fi
  echo "[lhf] creating $VENV"
  "$PYTHON" -m venv "$VENV"
}

_lhf_pip() { "$VENV/bin/python" -m pip --quiet --disable-pip-version-check "$@"; }

if [ "$newest" = 1 ]; then
  # Always a new resolve: the point is to see what the registry serves today.
  _lhf_fresh_venv
  echo "[lhf] installing lhf_hf[$extras] with the newest versions pyproject.toml allows into $VENV"
  _lhf_pip install --upgrade pip setuptools wheel
  _lhf_pip install --no-build-isolation -e "$ROOT[$extras]"
  _lhf_pip check
  _lhf_pip freeze --all --exclude lhf_hf > "$VENV/versions.txt"
  echo "[lhf] newest versions (diff against requirements.lock; < lock, > newest):"
  diff <(grep -v '^#' "$LOCK" | sort -f) <(sort -f "$VENV/versions.txt") || true
else
  if [ ! -f "$LOCK" ]; then
    echo "[lhf] $LOCK is missing: run scripts/lock.sh to create it" >&2
    return 1 2>/dev/null || exit 1
  fi
  key="$(cat "$ROOT/pyproject.toml" "$LOCK" | sha256sum | cut -c1-16) $("$PYTHON" -c 'import sys; print(sys.version.split()[0])')"
  # the stamp: "<key>" on line 1, then one line per installed extras set
  installed=""
  if [ -x "$VENV/bin/python" ] && [ -f "$STAMP" ] && [ "$(head -n1 "$STAMP")" = "$key" ] \
     && "$VENV/bin/python" -c "import lhf_hf" 2>/dev/null; then
    installed="$(tail -n +2 "$STAMP")"
  else
    if [ -e "$VENV" ]; then
      echo "[lhf] $VENV is stale or incomplete (lock, pyproject or Python changed, or an install was interrupted): rebuilding"
    fi
    _lhf_fresh_venv
  fi
  if ! grep -qxF "$extras" <<<"$installed"; then
    echo "[lhf] installing lhf_hf[$extras] into $VENV from requirements.lock (torch: the 2.13.0 CPU wheel)"
    rm -f "$STAMP"  # an install cut short leaves no stamp, so the next run starts afresh
    _lhf_pip install -c "$LOCK" pip setuptools wheel
    _lhf_pip install --no-build-isolation -c "$LOCK" -e "$ROOT[$extras]"
    _lhf_pip check
    printf '%s\n%s\n' "$key" "$(printf '%s\n%s' "$installed" "$extras" | sed '/^$/d')" > "$STAMP.tmp"
    mv "$STAMP.tmp" "$STAMP"
  fi
fi
export PATH="$VENV/bin:$PATH"
# Headless MuJoCo: never try to open a window.
export MUJOCO_GL="${MUJOCO_GL:-disable}"
