"""lhf reproduce --jobs: stages side by side in child processes, in dependency order."""

from __future__ import annotations

import json
import sys
import time
import types
from pathlib import Path

import pytest

from lhf_hf.reproduce import reproduce
from lhf_hf.reproduce.parallel import LOG_FILE, run_stages
from lhf_hf.reproduce.stages import DONE_FILE, Stage, StageRunner

# A stand-in stage process: records when it ran, then marks its stage done (or fails).
CHILD = """
import json, os, sys, time
out, fail, kind, config = sys.argv[1], sys.argv[2] == "1", sys.argv[3], json.loads(sys.argv[4])
t0 = time.time()
time.sleep(0.3)
print("working in", out, "threads", os.environ.get("OMP_NUM_THREADS"))
if fail:
    print("something broke"); sys.exit(3)
json.dump({"start": t0, "end": time.time(), "threads": os.environ.get("OMP_NUM_THREADS"),
           "pid": os.getpid()},
          open(os.path.join(out, "times.json"), "w"))
json.dump({"kind": kind, "config": config, "wall_s": 0.3}, open(os.path.join(out, "stage.json"), "w"))
"""


def _here(out: Path, fail: bool = False) -> None:
    """An in-process stage (collect, filter): records when it ran."""
    t0 = time.time()
    time.sleep(0.3)
    if fail:
        raise OSError("disk full")
    (out / "times.json").write_text(json.dumps({"start": t0, "end": time.time(), "pid": 0}))


def _child_only(out: Path) -> None:
    raise AssertionError("with jobs > 1, trainings and evaluations run in child processes")


def _graph(fail_filter: bool = False):
    """collect -> filter -> (train base, train lhf) -> one eval each; then a second collect."""
    col = Stage("collect", "collect", {"i": 0}, _here)
    fil = Stage("filter", "filter", {"i": 1}, lambda out: _here(out, fail_filter), (col,))
    tb = Stage("train", "train base", {"i": 2}, _child_only, (col,))
    tl = Stage("train", "train lhf", {"i": 3}, _child_only, (col, fil))
    eb = Stage("evaluate", "eval base", {"i": 4}, _child_only, (tb,))
    el = Stage("evaluate", "eval lhf", {"i": 5}, _child_only, (tl,))
    col2 = Stage("collect", "collect 2", {"i": 6}, _here)
    return [col, tb, fil, tl, eb, el, col2]  # a dependency order; the filter after a child


def _command(work: Path, failing: set[str] = frozenset()):
    return lambda s: [
        sys.executable, "-c", CHILD, str(s.path(work)), str(int(s.label in failing)), s.kind,
        json.dumps(s.config),
    ]  # fmt: skip


def _times(stages, work):
    return {s.label: json.loads((s.path(work) / "times.json").read_text()) for s in stages}


@pytest.mark.slow
def test_dependencies_first_at_most_jobs_at_once_and_collections_alone(tmp_path):
    stages = _graph()
    lines: list[str] = []
    runner = StageRunner(tmp_path, total=len(stages), echo=lines.append)
    run_stages(stages, runner, jobs=2, worker_command=_command(tmp_path), poll_s=0.02)
    t = _times(stages, tmp_path)
    for s in stages:  # every input ended before the stage started
        assert all(t[i.label]["end"] <= t[s.label]["start"] for i in s.inputs)
    events = sorted([(v["start"], 1) for v in t.values()] + [(v["end"], -1) for v in t.values()])
    level = peak = 0
    for _, d in events:
        level += d
        peak = max(peak, level)
    assert peak == 2  # two at once happened, never three
    for c in ("collect", "collect 2"):  # a collection uses every core: nothing beside it
        others = [v for k, v in t.items() if k != c]
        assert all(v["end"] <= t[c]["start"] or v["start"] >= t[c]["end"] for v in others)
    # collections first: the second run's collection did not wait for the first run's stages
    assert t["collect 2"]["end"] <= min(t[k]["start"] for k in ("train base", "train lhf"))
    # collections and filters here; trainings and evaluations in children with one thread
    assert {k for k, v in t.items() if v["pid"] == 0} == {"collect", "filter", "collect 2"}
    assert {v["threads"] for v in t.values() if v["pid"]} == {"1"}
    assert [e["stage"] for e in runner.log] and all(not e["cached"] for e in runner.log)
    assert (stages[1].path(tmp_path) / LOG_FILE).read_text().startswith("working in")
    # a child's stage whose mark is no record runs again
    mark = stages[1].path(tmp_path) / DONE_FILE  # "train base"
    mark.write_text("[]")
    redo = StageRunner(tmp_path, total=len(stages), echo=lines.append)
    run_stages(stages, redo, jobs=2, worker_command=_command(tmp_path), poll_s=0.02)
    assert stages[1].done(tmp_path)
    assert [e["stage"] for e in redo.log if not e["cached"]] == ["train base"]
    # the cache cannot tell: a sequential rerun finds every stage done
    again = StageRunner(tmp_path, total=len(stages), echo=lines.append)
    run_stages(stages, again, jobs=1, worker_command=None)
    assert all(e["cached"] for e in again.log)


@pytest.mark.slow
def test_a_failed_stage_stops_new_starts_and_names_its_log(tmp_path):
    stages = _graph()
    lines: list[str] = []
    runner = StageRunner(tmp_path, total=len(stages), echo=lines.append)
    cmd = _command(tmp_path, failing={"train base"})
    with pytest.raises(
        RuntimeError, match=r"1 stage\(s\) failed: \['train train base'\].*run the same"
    ):
        run_stages(stages, runner, jobs=2, worker_command=cmd, poll_s=0.02)
    text = "\n".join(lines)
    assert "[failed] train    train base (exit 3)" in text and "something broke" in text
    done = {s.label for s in stages if (s.path(tmp_path) / DONE_FILE).exists()}
    # what ran beside it finished and is kept; nothing that depends on it started
    assert {"collect", "filter", "train lhf"} <= done and "eval base" not in done
    assert not stages[4].path(tmp_path).exists()  # eval base


def test_a_sigterm_of_the_parent_reaches_the_running_children(tmp_path):
    # The CLI turns SIGTERM into an exception (utils.signals.Terminated); here the scheduler's own
    # call raises one while a child runs: the child is terminated at once, not waited on for 30 s.
    from lhf_hf.utils.signals import Terminated

    stages = _graph()
    started: list = []

    def command(s: Stage) -> list[str]:
        if started:
            raise Terminated(143)  # as if `kill` arrived when the second child was to start
        started.append(s)
        return [sys.executable, "-c", "import time; time.sleep(60)"]

    runner = StageRunner(tmp_path, total=len(stages), echo=lambda s: None)
    t0 = time.perf_counter()
    with pytest.raises(Terminated):
        run_stages(stages, runner, jobs=2, worker_command=command, poll_s=0.02)
    assert time.perf_counter() - t0 < 30  # the sleeping child was stopped, not awaited
    assert [s.label for s in started] == ["train base"] and not started[0].done(tmp_path)


def test_a_stage_failing_in_this_process_raises_its_error_after_the_children_end(tmp_path):
    stages = _graph(fail_filter=True)
    runner = StageRunner(tmp_path, total=len(stages), echo=lambda s: None)
    with pytest.raises(OSError, match="disk full"):
        run_stages(stages, runner, jobs=2, worker_command=_command(tmp_path), poll_s=0.02)
    # train base (started beside the filter) finished and is kept; train lhf never started
    assert (stages[1].path(tmp_path) / DONE_FILE).exists()
    assert not stages[3].path(tmp_path).exists()


def test_bad_plans_and_jobs_are_errors(tmp_path):
    stages = _graph()
    runner = StageRunner(tmp_path)
    with pytest.raises(ValueError, match="jobs must be an integer >= 1"):
        run_stages(stages, runner, jobs=0, worker_command=None)
    with pytest.raises(ValueError, match="reads stages that are not in the plan"):
        run_stages(stages[1:], runner, jobs=2, worker_command=_command(tmp_path))
    from lhf_hf.cli.main import main

    assert main(["reproduce", "darkroom-main", "--jobs", "0"]) == 1


@pytest.mark.slow
def test_reproduce_with_two_jobs_matches_the_plan_and_caches(tmp_path):
    from tests.reproduce.test_reproduce import TINY, _spec

    spec = _spec(tmp_path, TINY)
    work, out = tmp_path / "work", tmp_path / "out"
    lines: list[str] = []
    reproduce(spec, "quick", out=out, work=work, echo=lines.append, jobs=2)
    summary = json.loads((out / "results.json").read_text())
    assert summary["jobs"] == 2 and len(summary["stages"]) == 12
    assert not any(s["cached"] for s in summary["stages"])
    for kind in ("train", "evaluate"):
        assert len(list(work.glob(f"{kind}/*/{LOG_FILE}"))) == 4
    evals = [json.loads(p.read_text()) for p in work.glob("evaluate/*/eval/eval_results.json")]
    assert sorted(r["split_seed"] for r in evals) == [0, 0, 1, 1]
    # in this process, the same plan: all cached
    reproduce(spec, "quick", out=out, work=work, echo=lines.append)
    assert all(s["cached"] for s in json.loads((out / "results.json").read_text())["stages"])


@pytest.mark.slow
def test_children_plan_from_a_snapshot_of_the_spec(tmp_path):
    """Editing the spec file while a --jobs run goes on cannot reach the stages it starts."""
    import threading

    from tests.reproduce.test_reproduce import TINY, _spec

    spec = _spec(tmp_path, TINY)
    work, out = tmp_path / "work", tmp_path / "out"
    edited = json.loads(json.dumps(TINY))
    edited["presets"]["quick"]["evaluate"]["episodes"] = 3

    def edit(line: str) -> None:  # as soon as the first child starts, the user edits the spec
        if "process" in line and "episodes: 3" not in Path(spec).read_text():
            _spec(tmp_path, edited)

    lines: list[str] = []
    lock = threading.Lock()

    def echo(line: str) -> None:
        with lock:
            lines.append(line)
            edit(line)

    reproduce(spec, "quick", out=out, work=work, echo=echo, jobs=2)
    assert "episodes: 3" in Path(spec).read_text()  # the edit happened during the run
    evals = [json.loads(p.read_text()) for p in work.glob("evaluate/*/eval/eval_results.json")]
    assert len(evals) == 4 and {r["config"]["episodes"] for r in evals} == {2}
    (snap,) = work.glob("specs/*/tiny.yaml")
    assert "episodes: 2" in snap.read_text()


def test_a_stage_process_unwinds_on_sigterm(monkeypatch, tmp_path):
    """A stage's own process (--jobs > 1) gets terminate() from the parent: SIGTERM is raised as
    Terminated there, so the stage's output folder is put back or left resumable (Python's
    default SIGTERM ends the process with no `finally` run); the handler is restored after."""
    import os
    import signal

    from lhf_hf.reproduce import worker
    from lhf_hf.utils.signals import Terminated

    stage = types.SimpleNamespace(hash="abc123")
    unwound = []

    def run(self, s):
        assert s is stage
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(2)
        finally:
            unwound.append(True)

    monkeypatch.setattr(worker, "plan_stages", lambda exp, work, progress=True: ([stage], {}))
    monkeypatch.setattr(worker.StageRunner, "run", run)

    def guard(signum, frame):  # without the worker's handler: this, not the end of pytest
        unwound.append("not raised")

    original = signal.signal(signal.SIGTERM, guard)
    argv = ["darkroom-main", "quick", "--runs", "1", "--work", str(tmp_path), "--stage", "abc123"]
    try:
        with pytest.raises(Terminated) as info:
            worker.main(argv)
        assert signal.getsignal(signal.SIGTERM) is guard
    finally:
        signal.signal(signal.SIGTERM, original)
    assert info.value.code == 128 + signal.SIGTERM and unwound == [True]


def test_no_progress_reaches_every_stage_and_the_children(tmp_path, monkeypatch):
    """``lhf reproduce --no-progress``: every stage's work gets ``progress=False``, in this process
    or in a ``--jobs`` child (``--no-progress`` on its command line)."""
    import importlib

    from lhf_hf.reproduce import load_experiment, plan_stages, worker
    from lhf_hf.reproduce.parallel import worker_command

    module = importlib.import_module("lhf_hf.reproduce.reproduce")  # the module, not the function

    got = []
    for name in ("collect", "derive_half", "run_filter", "train", "evaluate"):
        monkeypatch.setattr(module, name, lambda *a, _n=name, **k: got.append((_n, k["progress"])))
    exp = load_experiment("darkroom-half", "quick", 1, ["ad"])  # every kind of stage
    for progress in (False, True):
        got.clear()
        stages, _ = plan_stages(exp, tmp_path / "w", progress=progress)
        for stage in stages:
            stage.fn(tmp_path / stage.kind)
        assert {n for n, _ in got} == {"collect", "derive_half", "run_filter", "train", "evaluate"}
        assert {p for _, p in got} == {progress}
    stage = types.SimpleNamespace(hash="abc")
    assert "--no-progress" in worker_command("x.yaml", "quick", 1, tmp_path, False)(stage)
    assert "--no-progress" not in worker_command("x.yaml", "quick", 1, tmp_path)(stage)
    planned = []
    monkeypatch.setattr(worker, "plan_stages", lambda e, w, p: planned.append(p) or ([], {}))
    argv = ["darkroom-main", "quick", "--runs", "1", "--work", str(tmp_path), "--stage", "abc"]
    assert worker.main([*argv, "--no-progress"]) == 2 and worker.main(argv) == 2  # no such stage
    assert planned == [False, True]
