"""Under ``accelerate launch`` (2 CPU processes) ranks split the tasks; the data is the same."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from lhf_hf.histories import load_histories
from lhf_hf.histories.writer import is_complete
from lhf_hf.utils.launcher import accelerate_config

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
    "--collector",
    "sb3",
    "--no-progress",
]


def _launch(out: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    accelerate = shutil.which("accelerate") or str(Path(sys.executable).parent / "accelerate")
    return subprocess.run(
        [
            accelerate,
            "launch",
            "--config_file",
            str(accelerate_config()),  # the one the package ships
            str(ROOT / "tests/launch_probe.py"),  # lhf as a program, saying how each rank ended
            *ARGS,
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, **(env or {})},
    )


@pytest.mark.slow
def test_accelerate_launch_two_ranks(tmp_path):
    r = _launch(tmp_path / "ranks")
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


@pytest.mark.slow
def test_a_failed_rank_is_named_by_the_ranks_waiting_for_it(tmp_path):
    """Rank 0 fails while rank 1 waits for it at the end of its share: rank 1's one line says
    that another rank stopped, not gloo's "Connection closed by peer" (which reads as a network
    fault); the folder stays an unfinished collection (nothing finalized)."""
    r = _launch(tmp_path / "ranks", {"LHF_PROBE_FAIL_RANK": "0"})
    assert r.returncode != 0
    assert "lhf collect: error: probe: rank 0 fails" in r.stderr, r.stderr[-2000:]
    # rank 1 is either waiting at the barrier (this line) or already stopped by the launcher
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("lhf collect:")]
    assert lines and all("Connection closed" not in ln for ln in lines), lines
    assert any(
        "rank 1 of 2: another rank stopped before reaching this point" in ln
        or ln == "lhf collect: terminated"
        for ln in lines
    ), lines
    assert not is_complete(tmp_path / "ranks")
