"""A collection killed mid-way and resumed equals an uninterrupted one (corrupt files are redone)."""

import os
import signal
import subprocess
import sys
import time

import pytest

from lhf_hf import constants as C
from lhf_hf.histories import load_histories

ARGS = [
    "darkroom",
    "--tasks",
    "5,6,7",
    "--histories",
    "4",
    "--steps",
    "100",
    "--protocol",
    "noisy",
    "--workers",
    "1",
    "--collector",
    "sb3",
    "--no-progress",
]


def lhf(*args, check=True):
    return subprocess.run(
        [sys.executable, "-m", "lhf_hf", *args], capture_output=True, text=True, check=check
    )


@pytest.mark.slow
def test_kill_resume_equals_uninterrupted(tmp_path):
    full = tmp_path / "full"
    lhf("collect", *ARGS, "--out", str(full))

    out = tmp_path / "killed"
    proc = subprocess.Popen(
        [sys.executable, "-m", "lhf_hf", "collect", *ARGS, "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    first = out / C.PARTS_DIR / "task-000000.json"
    deadline = time.time() + 120
    while not first.exists() and time.time() < deadline:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert first.exists(), "the first task should have been committed before the kill"
    assert not (out / C.INFO_PATH).exists()
    # A plain rerun is refused, loading says what to do.
    r = lhf("collect", *ARGS, "--out", str(out), check=False)
    assert r.returncode == 1 and "--resume" in r.stderr
    with pytest.raises(ValueError, match="--resume"):
        load_histories(out)
    # Corrupt the committed task: resume must notice and redo it.
    data = out / "data/chunk-000/file-000.parquet"
    data.write_bytes(data.read_bytes()[:-50])
    lhf("collect", *ARGS, "--out", str(out), "--resume")

    a, b = load_histories(full), load_histories(out)
    assert a.fingerprint == b.fingerprint
    assert a.frame_table().equals(b.frame_table())
    assert a.histories.data.table.equals(b.histories.data.table)
    assert a.episodes.data.table.equals(b.episodes.data.table)
    # resuming a finished dataset is a no-op
    r = lhf("collect", *ARGS, "--out", str(out), "--resume")
    assert "wrote" in r.stdout
