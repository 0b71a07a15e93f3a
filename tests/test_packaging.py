"""The wheel carries everything a non-editable install needs: card templates, experiment specs,
the kernel source, the accelerate launch config; and they are found from the package itself."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_wheel_contains_the_package_data(tmp_path):
    # --no-build-isolation: the build uses the venv's locked setuptools, no download
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
         "--wheel-dir", str(tmp_path), str(REPO)],
        check=True, cwd=tmp_path,
    )  # fmt: skip
    (wheel,) = tmp_path.glob("lhf_hf-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    package = REPO / "lhf_hf"
    data = [
        *package.glob("templates/*.md"),
        *package.glob("reproduce/experiments/*.yaml"),
        package / "reproduce" / "rates.json",
        *package.glob("collection/kernels/*.cpp"),
        *package.glob("modeling/kernels/*.cpp"),
        *package.glob("modeling/kernels/*.h"),
        *package.glob("launch/*.yaml"),
    ]
    assert len(data) >= 3 + 8 + 1 + 1 + 1 + 1 + 1 and all(p.exists() for p in data)
    missing = [
        str(p.relative_to(REPO)) for p in data if p.relative_to(REPO).as_posix() not in names
    ]
    assert not missing, f"not in {wheel.name}: {missing}"
    # the code itself, and nothing from outside the package (tests, results, scripts)
    assert "lhf_hf/cli/main.py" in names
    assert not [n for n in names if n.startswith(("tests/", "results/", "scripts/", "benchmarks/"))]


def test_specs_and_templates_are_found_inside_the_package():
    from lhf_hf.reproduce.experiment import EXPERIMENTS_DIR, experiment_names
    from lhf_hf.utils.launcher import accelerate_config
    from lhf_hf.utils.templates import template_path

    package = Path(__import__("lhf_hf").__file__).parent
    assert EXPERIMENTS_DIR.parent.parent == package
    assert {"darkroom-main", "darkroom-noisy", "metaworld-ml1"} <= set(experiment_names())
    for name in ("histories_card.md", "selection_card.md", "model_card.md"):
        assert template_path(name).parent.parent == package
    assert accelerate_config().parent.parent == package


@pytest.mark.parametrize("newest", ["0", "1"])
@pytest.mark.parametrize("with_cfg", [False, True])
def test_venv_script_never_replaces_a_folder_that_is_not_a_venv(tmp_path, newest, with_cfg):
    """scripts/_venv.sh rebuilds stale venvs by deleting them: only a folder holding nothing but a
    venv's own entries (a project with a pyvenv.cfg and files of its own stays)."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    if with_cfg:
        (mine / "pyvenv.cfg").write_text("home = /usr/bin\n")
    r = subprocess.run(
        ["bash", "-c", f"source {REPO / 'scripts' / '_venv.sh'} dev"],
        env={**os.environ, "LHF_VENV": str(mine), "LHF_NEWEST": newest, "PYTHON": "python3.11"},
        capture_output=True,
        text=True,
    )
    assert r.returncode != 0 and "is not a venv this script made" in r.stderr, r
    assert (mine / "notes.txt").read_text() == "keep"
