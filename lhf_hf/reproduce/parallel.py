"""``lhf reproduce --jobs J`` (docs/reproduce.md, ``parallel.py``): up to J stages at once, each
training or evaluation in a child process with one thread (two 1-thread trainings finish 1.3x
sooner than two 2-thread ones, BENCHMARKS.md), as soon as the stages it reads are done.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from lhf_hf.errors import UserError, UserRuntimeError

from .stages import LOG_FILE, Stage, StageRunner

#: Kinds of stage that use every core by themselves (collection: its own worker processes).
WHOLE_MACHINE = {"collect"}
#: Kinds of stage run in this process (short, or alone anyway); the others get a child process.
IN_PROCESS = {"collect", "derive", "filter"}
#: Environment of a child: one thread for torch and the BLAS it calls.
ONE_THREAD = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def check_jobs(jobs) -> None:
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise UserError(f"jobs must be an integer >= 1, got {jobs!r}")


def run_stages(
    stages: Sequence[Stage],
    runner: StageRunner,
    jobs: int,
    worker_command: Callable[[Stage], list[str]],
    poll_s: float = 0.2,
) -> None:
    """Run ``stages`` (in dependency order) with ``runner``: in this process when ``jobs == 1``,
    else up to ``jobs`` child processes at once (``worker_command(stage)`` starts one).  A failed
    stage stops new starts; the running ones finish, and the call raises."""
    check_jobs(jobs)
    if jobs == 1:
        for stage in stages:
            runner.run(stage)
        return
    work = runner.work
    known = {s.hash for s in stages}
    for s in stages:
        if not s.done(work) and any(i.hash not in known for i in s.inputs):
            raise UserError(f"stage {s.label!r} reads stages that are not in the plan")
    # collections (which read nothing) first: in plan order a later run's collection, which waits
    # for every running stage, held back everything after it
    pending = sorted(stages, key=lambda s: s.kind not in WHOLE_MACHINE)
    running: dict[subprocess.Popen, tuple[Stage, float, object]] = {}
    finished: set[str] = set()
    failed: list[str] = []
    error: Exception | None = None  # of a stage run in this process
    try:
        while pending or running:
            for stage in list(pending):
                done = stage.done(work)
                if failed or not done and any(i.hash not in finished for i in stage.inputs):
                    continue  # an input is still running (or waiting)
                if not done and len(running) >= (1 if stage.kind in WHOLE_MACHINE else jobs):
                    break  # first come, first served: a whole-machine stage is not starved
                pending.remove(stage)
                if done or stage.kind in IN_PROCESS:
                    try:
                        runner.run(stage)  # a done stage is reported as cached
                    except Exception as exc:  # noqa: BLE001 (re-raised once the children end)
                        failed.append(f"{stage.kind} {stage.label}")
                        error = exc
                        runner.echo(f"[failed] {stage.kind:<8} {stage.label}: {exc}")
                        break
                    finished.add(stage.hash)
                    continue
                log_path = stage.path(work) / LOG_FILE
                log_path.parent.mkdir(parents=True, exist_ok=True)
                log = open(log_path, "ab")  # noqa: SIM115 (closed when the child ends)
                child = subprocess.Popen(
                    worker_command(stage),
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    env={**os.environ, **ONE_THREAD},
                )
                runner.echo(
                    f"{runner.head(stage)} ... (process {child.pid}, 1 thread, log {log_path})"
                )
                running[child] = (stage, time.perf_counter(), log)
            if not running:
                if pending and not failed:
                    names = [s.label for s in pending]
                    raise RuntimeError(f"stages {names} wait for inputs that never ran")
                break
            time.sleep(poll_s)
            for child in [c for c in running if c.poll() is not None]:
                stage, t0, log = running.pop(child)
                log.close()
                if child.returncode == 0 and stage.done(work):
                    wall = round(time.perf_counter() - t0, 1)
                    finished.add(stage.hash)
                    runner.echo(f"[done] {stage.kind:<8} {stage.label} in {wall} s")
                    runner.record(stage, wall)
                else:
                    failed.append(f"{stage.kind} {stage.label}")
                    runner.echo(
                        f"[failed] {stage.kind:<8} {stage.label} (exit {child.returncode}); "
                        f"the end of {log.name}:\n{_tail(Path(log.name))}"
                    )
    except BaseException:
        # Interrupted: each child is told once, here, with SIGTERM (a stage process ignores
        # Ctrl-C, ``worker.py``, so a held-down Ctrl-C cannot cut its cleanup short); what they
        # finished or saved is kept and resumes on the next call.
        for child in running:
            child.terminate()
        if running:
            runner.echo(
                f"[lhf reproduce] interrupted: waiting up to 30 s for {len(running)} running "
                "stage(s) to stop (what they finished or saved is kept)"
            )
        for child, (stage, *_) in running.items():
            try:
                child.wait(timeout=30)
            except subprocess.TimeoutExpired:
                child.kill()  # a second SIGTERM would interrupt its cleanup; this ends it
                child.wait()
            state = "finished" if stage.done(work) else "stopped (resumes on the next call)"
            runner.echo(f"[{state.split()[0]}] {stage.kind:<8} {stage.label}: {state}")
        raise
    if error is not None:
        raise error
    if failed:
        raise UserRuntimeError(
            f"{len(failed)} stage(s) failed: {failed}; their logs are named above. Finished "
            "stages are cached: fix the cause and run the same command again to resume."
        )


def _tail(path: Path, lines: int = 15) -> str:
    text = path.read_text(errors="replace").replace("\r", "\n")  # progress bars: one line each
    kept = [ln for ln in text.splitlines() if ln.strip()][-lines:]
    return "\n".join("    " + ln for ln in kept)


def worker_command(
    experiment: str, preset: str, runs: int, work: Path, progress: bool = True
) -> Callable[[Stage], list[str]]:
    """The command that runs one stage of this experiment in a child process."""
    base = [sys.executable, "-m", "lhf_hf.reproduce.worker", str(experiment), preset]
    base += ["--runs", str(runs), "--work", str(Path(work).resolve())]
    base += [] if progress else ["--no-progress"]
    return lambda stage: [*base, "--stage", stage.hash]
