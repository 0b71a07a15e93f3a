"""Separate virtual environments for tests that run another project's own code against our
artifacts (LeRobot's reader), which pins versions ``.venv`` cannot share.

``locked_venv(name, python, lock)`` builds ``<repo>/.venv-<name>`` from a pip freeze once and
reuses it while the lock file is unchanged (its SHA-256 is kept in the venv); a failed build leaves
no venv that looks finished.  The interpreter is found on PATH or through pyenv; where it is
missing the test fails (CI must run it) unless ``LHF_SKIP_<NAME>=1`` says to skip.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def find_python(version: str) -> str | None:
    """``python3.X`` on PATH, else pyenv's interpreter of that minor version."""
    found = shutil.which(f"python{version}")
    if found:
        probe = subprocess.run([found, "--version"], capture_output=True, text=True)
        if probe.returncode == 0:  # a pyenv shim of an uninstalled version exits non-zero
            return found
    pyenv = Path(os.environ.get("PYENV_ROOT", Path.home() / ".pyenv")) / "versions"
    for candidate in sorted(pyenv.glob(f"{version}.*"), reverse=True):
        exe = candidate / "bin" / f"python{version}"
        if exe.exists():
            return str(exe)
    return None


def locked_venv(name: str, python_version: str, lock: Path) -> Path:
    """The venv's Python executable, built from ``lock`` (installed with ``--no-deps``: the lock is
    a complete freeze, so nothing is resolved anew)."""
    skip_var = f"LHF_SKIP_{name.upper()}"
    python = find_python(python_version)
    if python is None:
        if os.environ.get(skip_var) == "1":
            pytest.skip(f"no Python {python_version} here and {skip_var}=1")
        pytest.fail(
            f"this test needs Python {python_version} (for {name}'s own code); install it (e.g. "
            f"pyenv install {python_version}) or set {skip_var}=1 to skip it"
        )
    venv = ROOT / f".venv-{name}"
    stamp = venv / "lock.sha256"
    digest = hashlib.sha256(lock.read_bytes()).hexdigest()
    exe = venv / "bin" / "python"
    if stamp.exists() and stamp.read_text() == digest and exe.exists():
        return exe
    shutil.rmtree(venv, ignore_errors=True)
    subprocess.run([python, "-m", "venv", str(venv)], check=True)
    log = ROOT / f".venv-{name}.install.log"
    with log.open("w") as out:
        done = subprocess.run(
            [str(exe), "-m", "pip", "install", "--no-deps", "-r", str(lock)],
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    if done.returncode != 0:
        shutil.rmtree(venv, ignore_errors=True)
        pytest.fail(f"building .venv-{name} from {lock.name} failed: see {log}")
    stamp.write_text(digest)
    return exe
