"""``collect(config, out)``: run a collection to a dataset folder, in parallel, resumably.

(Not named ``collect.py``: a submodule of that name, once imported on its own, would rebind the
package attribute ``lhf_hf.collection.collect`` from this function to the module.)

Tasks are spread over ``config.workers`` processes and, under ``accelerate launch``, over ranks
(rank r takes task positions r, r + world, ...).  Every finished task is committed on its own
(``histories.writer.write_task``), so an interrupted run loses at most the tasks in flight;
``resume=True`` skips committed tasks and redoes half-written or corrupt ones.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from contextlib import ExitStack
from datetime import timedelta
from multiprocessing import get_context
from pathlib import Path

import torch
from tqdm.auto import tqdm

from lhf_hf import constants as C
from lhf_hf.configs.collect import COLLECTORS, CollectConfig
from lhf_hf.envs import get_spec
from lhf_hf.histories.reader import HistoryDataset, load_histories
from lhf_hf.histories.writer import (
    claim_dataset,
    finalize,
    is_complete,
    task_done,
    write_task,
)
from lhf_hf.utils.io import read_json
from lhf_hf.utils.launcher import end_ranks, wait_for_ranks
from lhf_hf.utils.signals import interrupts_ignored
from lhf_hf.utils.versions import library_versions

from . import backend_verdict
from .batched_collector import check_device, collect_chunk, resolve_ppo_backend
from .sb3_collector import collect_and_write_task


class _Ranks:
    """This process's rank under ``accelerate launch`` / torchrun (1 process otherwise)."""

    def __init__(self) -> None:
        self.world = int(os.environ.get("WORLD_SIZE", "1"))
        self.state = None
        if self.world > 1:
            from accelerate import PartialState  # deferred: 1.4 s, needed under a launcher only

            # A long timeout: ranks wait for each other's whole share of tasks at the barrier.
            self.state = PartialState(cpu=True, timeout=timedelta(hours=48))
            self.rank, self.world = self.state.process_index, self.state.num_processes
        else:
            self.rank = 0

    def barrier(self) -> None:
        if self.state is not None:
            wait_for_ranks(self.state)


class _Progress:
    """The progress bar of a collection: tasks done, transitions/s, ETA; a summary line at the end."""

    def __init__(
        self, config: CollectConfig, total: int, done: int, ranks: _Ranks, enabled: bool, label: str
    ) -> None:
        self.config, self.enabled, self.label = config, enabled, label
        if done:  # a resumed collection says what it goes on from (also without a bar; said
            # before the bar is drawn, not onto its line)
            print(
                f"collect {config.env_id}: resuming, {done} of {total} task(s) already committed",
                file=sys.stderr,
            )
        self.bar = tqdm(
            total=total,
            initial=done,
            unit="task",
            disable=not enabled,
            desc=f"collect {config.env_id}" + (f" [rank {ranks.rank}]" if ranks.world > 1 else ""),
        )
        self.tasks, self.frames, self.start = 0, 0, time.perf_counter()

    def update(self, tasks: int) -> None:
        self.tasks += tasks
        self.frames += tasks * self.config.frames_per_task
        self.bar.update(tasks)
        self.bar.set_postfix_str(
            f"{self.frames / (time.perf_counter() - self.start):,.0f} transitions/s"
        )

    def close(self) -> None:
        self.bar.close()
        if self.enabled and self.tasks:
            secs = time.perf_counter() - self.start
            print(
                f"collected {self.tasks} tasks ({self.frames:,} transitions) in {secs:.1f} s: "
                f"{self.frames / secs:,.0f} transitions/s ({self.label})",
                file=sys.stderr,
            )


def lhf_metadata(config: CollectConfig) -> dict:
    spec = get_spec(config.env_id)
    extra = list(spec.extra_packages)
    return {
        "collect": config.identity(),
        "tasks": list(config.tasks),
        "seed": config.seed,
        "terminal_convention": "truncation (episodes end at the horizon with truncated=True; SB3 bootstraps "
        "the value of the final state)",
        "versions": library_versions(extra),
        "derived_from": None,
        # where it ran: not part of the identity (the data are the same on any such machine)
        "machine": {
            **backend_verdict.machine(
                kernel=config.collector == "batched" and config.ppo_backend == "kernel"
            ),
            **(
                {"ppo_backend": config.ppo_backend, "ppo_verdict": backend_verdict.last_verdict()}
                if config.collector == "batched"
                else {}
            ),
        },
    }


def _run_sb3(
    config: CollectConfig, out: Path, tasks: list[int], ranks: _Ranks, progress: bool
) -> None:
    """One job per task, spread over worker processes."""
    mine = list(range(ranks.rank, len(tasks), ranks.world))
    todo = [p for p in mine if not task_done(out, p, config.frames_per_task)]
    config_dict = config.to_dict()
    bar = _Progress(
        config,
        len(mine),
        len(mine) - len(todo),
        ranks,
        progress,
        f"sb3, {config.workers} worker(s)",
    )
    try:
        if config.workers == 1 or len(todo) <= 1:
            for p in todo:
                collect_and_write_task(config_dict, tasks[p], p, str(out))
                bar.update(1)
        else:
            # spawn: torch and MuJoCo are not fork-safe once initialised.  Each worker watches this
            # process and exits when it is gone (kill -9 included), so no orphan keeps writing.
            pool = ProcessPoolExecutor(
                max_workers=min(config.workers, len(todo)),
                mp_context=get_context("spawn"),
                initializer=exit_with_parent,
                initargs=(os.getpid(),),
            )
            try:
                pending = {
                    pool.submit(collect_and_write_task, config_dict, tasks[p], p, str(out))
                    for p in todo
                }
                while pending:
                    # polled, not `wait(...)`: an interrupt inside `wait` can leave its waiter's
                    # lock held, and the pool's manager thread, which takes it to report a
                    # result, then blocks the interpreter's exit for good (a double Ctrl-C hung)
                    finished = {fut for fut in pending if fut.done()}
                    if not finished:
                        time.sleep(0.1)
                        continue
                    pending -= finished
                    for fut in finished:
                        fut.result()  # re-raises a worker's error; committed tasks stay
                        bar.update(1)
            except Exception:
                # A worker's error: the tasks in flight finish (and commit), queued ones are
                # dropped (`with pool` would have run every queued task before raising); an
                # interrupt while they finish stops them.
                try:
                    pool.shutdown(wait=True, cancel_futures=True)
                except BaseException:
                    stop_workers(pool)
                    raise
                raise
            except BaseException:
                stop_workers(pool)
                raise
            pool.shutdown(wait=True)
    finally:
        bar.close()


def stop_workers(pool: ProcessPoolExecutor) -> None:
    """An interrupt (Ctrl-C; SIGTERM, which ``utils.signals`` raises as ``Terminated`` and which
    reaches this process only): cancel the queued tasks and stop the running ones now.  A plain
    shutdown waits for every queued task (a SIGTERM'd 10-task Meta-World collection ran on for
    minutes, and Ctrl-C only failed the tasks in flight: a worker takes the next one after it).
    A stopped task has not committed; ``resume`` redoes it."""
    # A second Ctrl-C (a double press; `timeout` passing one on) must not cut this short: the
    # workers would go on with the queued tasks while the exit waits for them.
    with interrupts_ignored():
        terminate = getattr(pool, "terminate_workers", None)  # public from Python 3.14
        if terminate is not None:
            terminate()
            return
        workers = list((pool._processes or {}).values())  # noqa: SLF001 (3.11-3.13: no public API)
        for proc in workers:  # first: whatever happens next, no worker takes another task
            proc.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in workers:
            proc.join(timeout=30)


def exit_with_parent(parent: int, period_s: float = 0.5) -> None:
    """In a worker process: a daemon thread that ends the process once ``parent`` is gone (the
    worker is then re-parented, so its parent PID changes); queued tasks die with it."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(period_s)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def _run_batched(
    config: CollectConfig, out: Path, tasks: list[int], ranks: _Ranks, progress: bool
) -> None:
    """One job per chunk of ``tasks_per_chunk`` task positions, in this process (torch threads)."""
    K = config.tasks_per_chunk
    chunks = [
        list(range(c * K, min((c + 1) * K, len(tasks)))) for c in range((len(tasks) + K - 1) // K)
    ]
    mine = [c for c in range(len(chunks)) if c % ranks.world == ranks.rank]
    todo = [
        c for c in mine if not all(task_done(out, p, config.frames_per_task) for p in chunks[c])
    ]
    n_mine = sum(len(chunks[c]) for c in mine)
    bar = _Progress(
        config,
        n_mine,
        n_mine - sum(len(chunks[c]) for c in todo),
        ranks,
        progress,
        f"batched, PPO by {'the C++ kernel' if config.ppo_backend == 'kernel' else 'torch ops'}, "
        f"{torch_threads()} torch threads",
    )
    # A chunk's tasks are written by ``workers`` threads (each task has its own files; parquet
    # encoding and hashing release the GIL) in the background while the next chunk collects: writing
    # a Key-to-Door chunk takes ~27 core-seconds, and the rollouts leave a core mostly idle
    # (BENCHMARKS.md).  At most one chunk waits to be written, so memory stays bounded (~1.3 GB of
    # int64 histories per 243 Key-to-Door tasks); a writer's error is raised at the next chunk
    # boundary, and tasks already committed stay committed (--resume redoes the rest).
    writers = ThreadPoolExecutor(max_workers=config.workers, thread_name_prefix="lhf-write")
    pending: list = []  # (chunk, futures) of the chunk being written

    def drain() -> None:
        for c, jobs in pending:
            for job in jobs:
                job.result()  # re-raises a writer's error here
            bar.update(len(chunks[c]))
        pending.clear()

    try:
        for c in todo:
            histories = collect_chunk(config, [tasks[p] for p in chunks[c]], c, progress=progress)
            drain()  # the previous chunk's writes: at most one chunk in memory besides this one
            pending.append(
                (
                    c,
                    [
                        writers.submit(write_task, out, p, th, config.horizon)
                        for p, th in zip(chunks[c], histories, strict=True)
                    ],
                )
            )
            del histories
        drain()
    finally:
        # on an error: queued writes are dropped (never half-done), running ones finish
        writers.shutdown(cancel_futures=True)
        bar.close()


def torch_threads() -> int:
    return torch.get_num_threads()


#: Collectors by name (``CollectConfig.collector``): each runs this rank's share of the tasks.
RUNNERS = {"sb3": _run_sb3, "batched": _run_batched}


def started_collector(out: str | Path) -> str | None:
    """The collector an unfinished or finished collection in ``out`` was started with (None: no
    collection there).  ``--collector`` unset and ``--resume``: that one goes on, whatever the
    default is now."""
    try:
        found = read_json(Path(out) / C.CONFIG_PATH).get("collector")
    except (OSError, ValueError):
        return None
    return found if found in COLLECTORS else None


def collect(
    config: CollectConfig,
    out: str | Path,
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
) -> HistoryDataset:
    """Collect ``config`` into ``out`` and return the finished dataset."""
    out = Path(out)
    if config.collector == "batched":
        check_device(config.device)  # before anything is written
        config.ppo_backend = resolve_ppo_backend(config)  # stored resolved: part of the identity
    ranks = _Ranks()
    # every rank decides the same way (no rank left at a barrier)
    complete = resume and is_complete(out)
    started = (out / C.CONFIG_PATH).is_file()
    with ExitStack() as claim:
        if ranks.rank == 0:  # rank 0 holds the folder; a complete dataset is only re-opened
            claim.enter_context(
                claim_dataset(out, config.identity(), resume=resume, overwrite=overwrite)
            )
            if resume and not started and not complete:
                # a fresh start is what `lhf reproduce` (resume if present) wants, but a user
                # who typed --resume expected a folder: said, not silent (a wrong --out shows)
                print(
                    f"collect {config.env_id}: --resume: {out} held no collection; starting one",
                    file=sys.stderr,
                )
        if complete:
            end_ranks()
            return load_histories(out) if ranks.rank == 0 else None  # type: ignore[return-value]
        ranks.barrier()
        return _collect_into(config, out, ranks, progress)


def _collect_into(config: CollectConfig, out: Path, ranks: _Ranks, progress: bool):
    tasks = list(config.tasks)
    RUNNERS[config.collector](config, out, tasks, ranks, progress)
    end_ranks()
    if ranks.rank != 0:
        return None  # type: ignore[return-value]
    names = get_spec(config.env_id).state_names
    feature_names = {C.OBS: list(names), C.NEXT_OBS: list(names)} if names else None
    return finalize(
        out,
        env_id=config.env_id,
        tasks=tasks,
        histories=config.histories,
        steps=config.steps,
        horizon=config.horizon,
        lhf_meta=lhf_metadata(config),
        split_seed=config.split_seed,
        feature_names=feature_names,
    )
