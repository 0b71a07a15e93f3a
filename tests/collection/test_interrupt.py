"""An interrupted multi-worker collection stops now: queued tasks are not run, running ones are
stopped, and ``--resume`` finishes the dataset."""

import os
import signal
import subprocess
import sys
import time

import pytest

from lhf_hf import constants as C
from lhf_hf.histories import load_histories

TASKS = 12
ARGS = [
    "darkroom",
    "--tasks",
    ",".join(str(t) for t in range(TASKS)),
    "--histories",
    "4",
    "--steps",
    "2000",
    "--workers",
    "2",
    "--no-progress",
]


def committed(out):
    return sorted((out / C.PARTS_DIR).glob("task-*.json"))


@pytest.mark.slow
def test_a_double_ctrl_c_stops_the_collection(tmp_path):
    """Two SIGINTs to the process group close together (a double press, or `timeout` passing one
    on): the command ends, as after one, and no worker goes on with the queued tasks."""
    out = tmp_path / "d"
    proc = subprocess.Popen(
        [sys.executable, "-m", "lhf_hf", "collect", *ARGS, "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own group: the test's Ctrl-C
    )
    deadline = time.time() + 300
    while not committed(out) and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)
    time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise
    assert proc.returncode == 130, err[-2000:]
    at_exit = committed(out)
    assert len(at_exit) < TASKS
    time.sleep(3)
    assert committed(out) == at_exit


@pytest.mark.slow
def test_sigterm_stops_queued_and_running_tasks(tmp_path):
    out = tmp_path / "d"
    proc = subprocess.Popen(
        [sys.executable, "-m", "lhf_hf", "collect", *ARGS, "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 300
    while not committed(out) and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert committed(out), "a first task should have been committed"
    os.kill(proc.pid, signal.SIGTERM)  # reaches the parent only, as `kill` and `timeout` do
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM, err[-2000:]
    assert "terminated" in err
    at_exit = committed(out)
    # Before the fix every queued task still ran: all 12 were committed when the command ended.
    assert len(at_exit) < TASKS
    time.sleep(3)  # no worker outlives the command and commits afterwards
    assert committed(out) == at_exit

    r = subprocess.run(
        [sys.executable, "-m", "lhf_hf", "collect", *ARGS, "--out", str(out), "--resume"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    info = load_histories(out).info
    assert (info["total_tasks"], info["total_histories"]) == (TASKS, TASKS * 4)
