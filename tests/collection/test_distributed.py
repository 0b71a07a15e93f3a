"""Under ``accelerate launch`` (2 CPU processes) ranks split the tasks; the data is the same."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from lhf_hf.histories import load_histories

ROOT = Path(__file__).resolve().parents[2]
ARGS = [
    "collect",
    "darkroom",
    "--tasks",
    "5,6,7",
    "--histories",
    "2",
    "--steps",
    "40",
    "--workers",
    "1",
    "--no-progress",
]


@pytest.mark.slow
def test_accelerate_launch_two_ranks(tmp_path):
    accelerate = shutil.which("accelerate") or str(Path(sys.executable).parent / "accelerate")
    r = subprocess.run(
        [
            accelerate,
            "launch",
            "--config_file",
            str(ROOT / "training/accelerate/cpu_2proc.yaml"),
            str(ROOT / "tests/launch_probe.py"),  # lhf as a program, saying how each rank ended
            *ARGS,
            "--out",
            str(tmp_path / "ranks"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert "[rank 1] committed" in r.stdout, "two processes should have run"
    for rank in (0, 1):  # each rank destroyed its process group before exiting
        assert f"rank {rank}: process group alive at exit: False" in r.stderr, r.stderr[-2000:]
    subprocess.run(
        [sys.executable, "-m", "lhf_hf", *ARGS, "--out", str(tmp_path / "one")],
        check=True,
        capture_output=True,
    )
    a, b = load_histories(tmp_path / "ranks"), load_histories(tmp_path / "one")
    assert a.fingerprint == b.fingerprint and a.frame_table().equals(b.frame_table())
