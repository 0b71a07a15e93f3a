"""An interrupted multi-worker collection stops now: queued tasks are not run, running ones are
stopped, and ``--resume`` finishes the dataset."""

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from lhf_hf import constants as C
from lhf_hf.histories import load_histories
from lhf_hf.utils.outputs import MARKER

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
    "--collector",
    "sb3",
    "--no-progress",
]


def committed(out):
    return sorted((out / C.PARTS_DIR).glob("task-*.json"))


def _started(out, **popen):
    """A 2-worker collection into ``out``, once its first task is committed."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "lhf_hf", "collect", *ARGS, "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        **popen,
    )
    deadline = time.time() + 300
    while not committed(out) and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert committed(out), "a first task should have been committed"
    return proc


def _ended_early(proc, out, returncode):
    """The command ended with ``returncode`` before every task ran, and no worker outlives it."""
    try:
        _, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise
    assert proc.returncode == returncode, err[-2000:]
    at_exit = committed(out)
    # Before the fix every queued task still ran: all 12 were committed when the command ended.
    assert len(at_exit) < TASKS
    time.sleep(3)  # no worker commits after the command ended
    assert committed(out) == at_exit
    return err


@pytest.mark.slow
def test_a_double_ctrl_c_stops_the_collection(tmp_path):
    """Two SIGINTs to the process group close together (a double press, or `timeout` passing one
    on): the command ends, as after one, and no worker goes on with the queued tasks."""
    out = tmp_path / "d"
    proc = _started(out, start_new_session=True)  # its own group: the test's Ctrl-C
    os.killpg(proc.pid, signal.SIGINT)
    time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)
    _ended_early(proc, out, 130)


@pytest.mark.slow
def test_ctrl_c_pressed_until_the_command_ends(tmp_path):
    """SIGINT every 20 ms from the first until the process is gone: each lands somewhere else (the
    workers' stop, the folders' cleanup, the interpreter's exit).  The exit puts SIGINT's default
    action back before torch's libraries unload: one landing there killed the process (-2)."""
    out = tmp_path / "d"
    proc = _started(out, start_new_session=True)
    ticker = threading.Event()

    def press():
        while not ticker.is_set():
            with contextlib.suppress(ProcessLookupError):  # gone: nothing left to interrupt
                os.killpg(proc.pid, signal.SIGINT)
            time.sleep(0.02)

    thread = threading.Thread(target=press, daemon=True)
    thread.start()
    try:
        _ended_early(proc, out, 130)
    finally:
        ticker.set()
        thread.join()


@pytest.mark.slow
def test_sigterm_stops_queued_and_running_tasks(tmp_path):
    out = tmp_path / "d"
    proc = _started(out, start_new_session=True)
    os.kill(proc.pid, signal.SIGTERM)  # reaches the parent only, as `kill` and `timeout` do
    assert "terminated" in _ended_early(proc, out, 128 + signal.SIGTERM)
    r = subprocess.run(
        [sys.executable, "-m", "lhf_hf", "collect", *ARGS, "--out", str(out), "--resume"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    ds = load_histories(out)
    assert (ds.info["total_tasks"], ds.lhf["total_histories"]) == (TASKS, TASKS * 4)


@pytest.mark.slow
def test_ctrl_c_during_the_batched_ppo_kernel_exits_cleanly(tmp_path):
    """The batched collector's PPO kernel runs in pieces on a thread pool, through raw pointers
    to the rollout's tensors: interrupted, the command waits for the running pieces before it
    unwinds.  It used to print "interrupted" and crash with a segfault (rc 139, 3 of 3 tries)."""
    out = tmp_path / "b"
    args = ["darkroom", "--collector", "batched", "--tasks", "train", "--histories", "20",
            "--steps", "1000", "--no-progress", "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(
        [sys.executable, "-m", "lhf_hf", "collect", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    deadline = time.time() + 300
    while not (out / MARKER).exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    time.sleep(5)  # learning: most of a chunk's time is PPO updates in the kernel's threads
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-2000:]
