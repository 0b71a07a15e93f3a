"""``lhf reproduce --jobs 2`` under a held-down Ctrl-C: each stage process is told to stop once,
unwinds whole (its checkpoint kept), and the command ends with 130 and no process left."""

import contextlib
import os
import re
import signal
import subprocess
import sys
import threading
import time

import pytest
import yaml

from lhf_hf.training.trainer import last_checkpoint
from tests.reproduce.test_reproduce import TINY

SPEC = {
    **TINY,
    "presets": {
        "quick": {
            **TINY["presets"]["quick"],
            "runs": 1,
            # long enough to be interrupted, a checkpoint early
            "train": {"preset": "tiny", "max_steps": 100000, "batch_size": 4, "save_steps": 5},
        }
    },
}


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


@pytest.mark.slow
def test_ctrl_c_held_down_stops_every_stage_once(tmp_path):
    spec = tmp_path / "interrupted.yaml"
    spec.write_text(yaml.safe_dump(SPEC))
    work, log = tmp_path / "work", tmp_path / "log.txt"
    cmd = [sys.executable, "-m", "lhf_hf", "reproduce", str(spec), "--preset", "quick",
           "--jobs", "2", "--work", str(work), "--out", str(tmp_path / "report")]  # fmt: skip
    with open(log, "w") as f:
        proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.time() + 300
        models = []
        while time.time() < deadline and proc.poll() is None:
            models = sorted(work.glob("train/*/model"))
            if len(models) == 2 and all(last_checkpoint(m) for m in models):
                break
            time.sleep(0.2)
        assert len(models) == 2 and all(last_checkpoint(m) for m in models), log.read_text()
        pressing = threading.Event()

        def press():  # Ctrl-C held down: SIGINT to the process group every 20 ms
            while not pressing.is_set():
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGINT)
                time.sleep(0.02)

        thread = threading.Thread(target=press, daemon=True)
        thread.start()
        try:
            proc.wait(timeout=120)
        finally:
            pressing.set()
            thread.join()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    out = log.read_text()
    assert proc.returncode == 130, out[-3000:]
    # the parent waited for both stages and said so (a second press used to end its wait early)
    assert out.count("[stopped] train") == 2, out[-3000:]
    for pid in re.findall(r"\(process (\d+),", out):
        assert _gone(int(pid))
    for model in models:
        stage_log = (model.parent / "stage.log").read_text(errors="replace")
        # the stage unwound once: no second interrupt inside its cleanup
        assert "During handling of the above exception" not in stage_log, stage_log[-3000:]
        assert last_checkpoint(model) is not None  # what it saved is kept for the next call
