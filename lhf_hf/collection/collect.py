"""``collect(config, out)``: run a collection to a dataset folder, in parallel, resumably.

Tasks are spread over ``config.workers`` processes and, under ``accelerate launch``, over ranks
(rank r takes task positions r, r + world, ...).  Every finished task is committed on its own
(``histories.writer.write_task``), so an interrupted run loses at most the tasks in flight;
``resume=True`` skips committed tasks and redoes half-written or corrupt ones.
"""

from __future__ import annotations

import os
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from datetime import timedelta
from multiprocessing import get_context
from pathlib import Path

from tqdm.auto import tqdm

from lhf_hf import constants as C
from lhf_hf.configs.collect import CollectConfig
from lhf_hf.envs import get_spec
from lhf_hf.histories.reader import HistoryDataset, load_histories
from lhf_hf.histories.writer import (
    finalize,
    is_complete,
    library_versions,
    prepare_output,
    task_done,
    write_task,
)

from .batched_collector import collect_chunk
from .sb3_collector import collect_and_write_task


class _Ranks:
    """This process's rank under ``accelerate launch`` / torchrun (1 process otherwise)."""

    def __init__(self) -> None:
        self.world = int(os.environ.get("WORLD_SIZE", "1"))
        self.state = None
        if self.world > 1:
            from accelerate import PartialState

            # A long timeout: ranks wait for each other's whole share of tasks at the barrier.
            self.state = PartialState(cpu=True, timeout=timedelta(hours=48))
            self.rank, self.world = self.state.process_index, self.state.num_processes
        else:
            self.rank = 0

    def barrier(self) -> None:
        if self.state is not None:
            self.state.wait_for_everyone()


def lhf_metadata(config: CollectConfig) -> dict:
    spec = get_spec(config.env_id)
    extra = ["metaworld", "mujoco"] if spec.family == "metaworld" else []
    return {
        "collect": config.identity(),
        "tasks": list(config.tasks),
        "seed": config.seed,
        "terminal_convention": "truncation (episodes end at the horizon with truncated=True; SB3 bootstraps "
        "the value of the final state)",
        "versions": library_versions(extra),
        "derived_from": None,
    }


def _run_sb3(
    config: CollectConfig, out: Path, tasks: list[int], ranks: _Ranks, progress: bool
) -> None:
    """One job per task, spread over worker processes."""
    mine = list(range(ranks.rank, len(tasks), ranks.world))
    todo = [p for p in mine if not task_done(out, p, config.frames_per_task)]
    config_dict = config.to_dict()
    bar = tqdm(
        total=len(mine),
        initial=len(mine) - len(todo),
        unit="task",
        disable=not progress,
        desc=f"collect {config.env_id}" + (f" [rank {ranks.rank}]" if ranks.world > 1 else ""),
    )
    frames, start = 0, time.perf_counter()

    def done(frames_task: int) -> None:
        nonlocal frames
        frames += frames_task
        bar.update(1)
        bar.set_postfix_str(f"{frames / (time.perf_counter() - start):,.0f} transitions/s")

    try:
        if config.workers == 1 or len(todo) <= 1:
            for p in todo:
                done(collect_and_write_task(config_dict, tasks[p], p, str(out))[1])
        else:
            # spawn: torch and MuJoCo are not fork-safe once initialised.
            with ProcessPoolExecutor(
                max_workers=min(config.workers, len(todo)), mp_context=get_context("spawn")
            ) as pool:
                pending = {
                    pool.submit(collect_and_write_task, config_dict, tasks[p], p, str(out))
                    for p in todo
                }
                while pending:
                    finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                    for fut in finished:
                        done(fut.result()[1])  # re-raises a worker's error; committed tasks stay
    finally:
        bar.close()
    if progress and todo:
        secs = time.perf_counter() - start
        print(
            f"collected {len(todo)} tasks ({frames:,} transitions) in {secs:.1f} s: "
            f"{frames / secs:,.0f} transitions/s with {config.workers} worker(s)",
            file=sys.stderr,
        )


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
    bar = tqdm(
        total=n_mine,
        initial=n_mine - sum(len(chunks[c]) for c in todo),
        unit="task",
        disable=not progress,
        desc=f"collect {config.env_id} (batched)"
        + (f" [rank {ranks.rank}]" if ranks.world > 1 else ""),
    )
    frames, start = 0, time.perf_counter()
    try:
        for c in todo:
            histories = collect_chunk(config, [tasks[p] for p in chunks[c]], c, progress=progress)
            for p, th in zip(chunks[c], histories, strict=True):
                write_task(out, p, th, config.horizon)
            frames += len(chunks[c]) * config.frames_per_task
            bar.update(len(chunks[c]))
            bar.set_postfix_str(f"{frames / (time.perf_counter() - start):,.0f} transitions/s")
    finally:
        bar.close()
    if progress and todo:
        secs = time.perf_counter() - start
        print(
            f"collected {frames // config.frames_per_task} tasks ({frames:,} transitions) in {secs:.1f} s: "
            f"{frames / secs:,.0f} transitions/s (batched, {torch_threads()} torch threads)",
            file=sys.stderr,
        )


def torch_threads() -> int:
    import torch

    return torch.get_num_threads()


#: Collectors by name (``CollectConfig.collector``): each runs this rank's share of the tasks.
RUNNERS = {"sb3": _run_sb3, "batched": _run_batched}


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
    ranks = _Ranks()
    complete = resume and is_complete(
        out
    )  # every rank decides the same way (no rank left at a barrier)
    if ranks.rank == 0:
        # a complete dataset is only re-opened: same config, or a clear error
        prepare_output(out, config.identity(), resume=resume, overwrite=overwrite)
    ranks.barrier()
    if complete:
        return load_histories(out) if ranks.rank == 0 else None  # type: ignore[return-value]

    tasks = list(config.tasks)
    RUNNERS[config.collector](config, out, tasks, ranks, progress)
    ranks.barrier()
    if ranks.rank != 0:
        return None  # type: ignore[return-value]
    feature_names = (
        {C.OBS: ["row", "col"], C.NEXT_OBS: ["row", "col"]}
        if get_spec(config.env_id).family == "gridworld"
        else None
    )
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
