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
# A relative LHF_VENV is relative to where the user ran the command (test.sh / demo.sh resolve it
# before they cd to the repository root).
if [ "$newest" = 1 ]; then
  VENV="${LHF_VENV:-$ROOT/.venv-newest}"
else
  VENV="${LHF_VENV:-$ROOT/.venv}"
fi
STAMP="$VENV/.lhf-install"
LOG="$VENV.install.log"

_lhf_fail() { echo "[lhf] $*" >&2; return 1 2>/dev/null || exit 1; }

# The lock was resolved and tested on CPython 3.11 (torch is its cp311 CPU wheel): check the
# interpreter before anything is built or removed.
command -v "$PYTHON" >/dev/null 2>&1 || _lhf_fail "PYTHON=$PYTHON: no such interpreter (set PYTHON=python3.11)"
pyver="$("$PYTHON" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null)" \
  || _lhf_fail "PYTHON=$PYTHON does not run (set PYTHON=python3.11)"
if [ "$pyver" != "3.11" ]; then
  _lhf_fail "PYTHON=$PYTHON is Python $pyver; requirements.lock was tested on CPython 3.11 (set PYTHON=python3.11)"
fi

# A folder we may delete and rebuild: empty, or holding nothing but what `python -m venv` and this
# script put there.  LHF_VENV may name any folder: a project with a pyvenv.cfg and files of its own
# is not ours to remove.
_lhf_is_our_venv() {
  [ -d "$VENV" ] || return 1
  local entry
  for entry in "$VENV"/* "$VENV"/.[!.]*; do
    [ -e "$entry" ] || continue
    case "$(basename "$entry")" in
      bin|lib|lib64|include|share|pyvenv.cfg|.gitignore|.lhf-install|.lhf-install.tmp|versions.txt) ;;
      *) return 1 ;;
    esac
  done
}

_lhf_fresh_venv() {
  if [ -e "$VENV" ] || [ -L "$VENV" ]; then
    _lhf_is_our_venv || _lhf_fail "$VENV exists and is not a venv this script made (it holds other files, or is a file): refusing to replace it; choose another LHF_VENV"
    rm -rf "$VENV"
  fi
  echo "[lhf] creating $VENV"
  "$PYTHON" -m venv "$VENV"
}

# pip's resolver explains a conflict only in its full output: keep that in a log, show its end on
# failure.
_lhf_pip() {
  if ! "$VENV/bin/python" -m pip --disable-pip-version-check "$@" >>"$LOG" 2>&1; then
    echo "[lhf] pip $* failed; the end of $LOG:" >&2
    grep -v "^WARNING: Location" "$LOG" | tail -n 25 >&2
    return 1
  fi
}

# The venv works: its interpreter imports the installed package and its main dependencies (-I: not
# from the current folder, which may be the source tree), and the console script is there.
_lhf_healthy() {
  [ -x "$VENV/bin/python" ] && [ -x "$VENV/bin/lhf" ] && (cd / && "$VENV/bin/python" -I -c \
    "import lhf_hf.cli.main, torch, transformers, datasets, accelerate, stable_baselines3" 2>/dev/null)
}

if [ "$newest" = 1 ]; then
  # Always a new resolve: the point is to see what the registry serves today.
  _lhf_fresh_venv
  : > "$LOG"
  echo "[lhf] installing lhf_hf[$extras] with the newest versions pyproject.toml allows into $VENV"
  _lhf_pip install --upgrade pip setuptools wheel
  _lhf_pip install --no-build-isolation -e "$ROOT[$extras]"
  _lhf_pip check
  _lhf_pip freeze --all --exclude lhf_hf > "$VENV/versions.txt"
  if diff -q <(grep -v '^#' "$LOCK" | sort -f) <(sort -f "$VENV/versions.txt") >/dev/null; then
    echo "[lhf] newest versions: the same as requirements.lock"
  else
    echo "[lhf] newest versions (diff against requirements.lock; < lock, > newest):"
    diff <(grep -v '^#' "$LOCK" | sort -f) <(sort -f "$VENV/versions.txt") || true
  fi
else
  [ -f "$LOCK" ] || _lhf_fail "$LOCK is missing: run scripts/lock.sh to create it"
  key="$(cat "$ROOT/pyproject.toml" "$LOCK" | sha256sum | cut -c1-16) $("$PYTHON" -c 'import sys; print(sys.version.split()[0])')"
  # the stamp: "<key>" on line 1, then one line per installed extras set
  installed=""
  if [ -f "$STAMP" ] && [ "$(head -n1 "$STAMP")" = "$key" ] && _lhf_healthy; then
    installed="$(tail -n +2 "$STAMP")"
  else
    if [ -e "$VENV" ] && _lhf_is_our_venv; then
      echo "[lhf] $VENV is stale or broken (lock, pyproject or Python changed, an install was interrupted, or its packages no longer import): rebuilding"
    fi
    _lhf_fresh_venv
  fi
  if ! grep -qxF "$extras" <<<"$installed"; then
    echo "[lhf] installing lhf_hf[$extras] into $VENV from requirements.lock (torch: the 2.13.0 CPU wheel)"
    rm -f "$STAMP"  # an install cut short leaves no stamp, so the next run starts afresh
    : > "$LOG"
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
