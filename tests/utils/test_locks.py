"""Lock files (``lhf_hf.utils.outputs``): deleted when let go, and still one holder at a time.

Deleting a lock file opens a race: a process that opened the file before its holder deleted it
locks a file no longer at the path, while a third process creates and locks a new one.  The first
test plays that interleaving out step by step (threads hold separate ``flock``s, as processes do);
the second has processes increment a shared counter under the lock."""

from __future__ import annotations

import multiprocessing
import threading
from pathlib import Path

from lhf_hf.utils import outputs
from lhf_hf.utils.outputs import file_lock, output_folder


class _Flock:
    """``fcntl`` as ``outputs`` sees it, with ``flock`` calls of the thread ``who`` reported
    (and its first one held back until ``go`` is set)."""

    def __init__(self, real, who: str):
        self.real, self.who = real, who
        self.LOCK_EX, self.LOCK_NB = real.LOCK_EX, real.LOCK_NB
        self.calls = 0
        self.called = threading.Event()  # B reached a flock call
        self.go = threading.Event()

    def flock(self, fd, op):
        if threading.current_thread().name == self.who:
            self.calls += 1
            self.called.set()
            if self.calls == 1:
                self.go.wait()
        return self.real.flock(fd, op)


def test_a_waiter_on_a_deleted_lock_file_takes_the_lock_again(tmp_path, monkeypatch):
    path = tmp_path / ".x.lock"
    fake = _Flock(outputs.fcntl, who="B")
    monkeypatch.setattr(outputs, "fcntl", fake)
    inside = []  # who holds the lock, in order of entering
    b_in = threading.Event()

    def b():
        with file_lock(path):
            inside.append("B")
            b_in.set()

    with file_lock(path):  # A
        inside.append("A")
        thread = threading.Thread(target=b, name="B")
        thread.start()
        assert fake.called.wait(60)  # B opened A's file and is about to lock it
        fake.called.clear()
    assert not path.exists()  # A deleted its file when it let go
    with file_lock(path):  # C: a new file at the path
        inside.append("C")
        fake.go.set()  # B now locks A's deleted file: it must see that and wait for C's
        assert fake.called.wait(60)  # B's second flock call, on C's file
        assert fake.calls == 2 and not b_in.is_set() and inside == ["A", "C"]
    thread.join(60)
    assert inside == ["A", "C", "B"] and not path.exists()


def _count(path: str, lock: str, times: int) -> None:
    for _ in range(times):
        with file_lock(Path(lock)):
            n = int(Path(path).read_text())
            Path(path).write_text(str(n + 1))


def test_processes_increment_under_the_lock(tmp_path):
    counter, lock = tmp_path / "n", tmp_path / ".n.lock"
    counter.write_text("0")
    ctx = multiprocessing.get_context("spawn")
    procs = [ctx.Process(target=_count, args=(str(counter), str(lock), 40)) for _ in range(4)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
    assert [p.exitcode for p in procs] == [0] * 4
    assert counter.read_text() == "160" and not lock.exists()  # no update lost, no file left


def test_output_folders_leave_no_lock_file(tmp_path):
    with output_folder(tmp_path / "out", "model") as out:
        assert (tmp_path / ".out.lock").read_text().strip().isdigit()  # the writer's PID
        (out / "w").write_text("1")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
