"""Datasets derived from a history dataset, task by task, through the same writer.

``half``: the first part of every history (paper, "Can LHF enhance ICRL given partial learning
histories?", first 50%).  LHF materialisation (``lhf_hf.filtering.materialize``) uses the same path.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tqdm.auto import tqdm

from lhf_hf.errors import UserError
from lhf_hf.utils.io import write_bytes_atomic
from lhf_hf.utils.versions import library_versions

from .checks import check_dataset
from .reader import HistoryDataset, load_histories
from .schema import TaskHistories
from .writer import claim_dataset, finalize, is_complete, task_done, write_task


def write_derived(
    source: HistoryDataset,
    out: str | Path,
    transform: Callable[[int, TaskHistories], TaskHistories],
    derived: dict,
    *,
    steps: int,
    identity: dict,
    overwrite: bool = False,
    resume: bool = False,
    progress: bool = True,
    inputs: Iterable[str | Path | None] = (),
    extra_files: dict[str, Path] | None = None,
    defer_to: list | None = None,
) -> HistoryDataset:
    """Write ``transform(task, histories)`` for every task of ``source`` as a new dataset at ``out``.

    ``derived`` (op, description, ...) is stored as ``meta/lhf_info.json["derived_from"]`` together
    with the source's path, fingerprint and collection config.  ``out`` may not be, contain or lie
    in the source or any of ``inputs``.  ``extra_files`` (path in the dataset -> file to copy,
    e.g. the selection's plot) are written before the folder's manifest, so ``lhf verify`` knows
    them.  ``defer_to``: switch together with an enclosing artifact (``utils.outputs``).
    """
    # A derived dataset records the source's fingerprint as its origin: a source whose files no
    # longer hash to it (or whose returns disagree with its rewards) would pass that on as sound.
    problems = check_dataset(source, full=True)
    if problems:
        raise UserError(
            f"the source dataset {source.root} fails `lhf verify` ({'; '.join(problems[:3])}): "
            "nothing derived from it"
        )
    tasks = [int(t) for t in source.lhf["tasks"]]
    H = source.lhf["histories_per_task"]
    identity = {**identity, "source_fingerprint": source.fingerprint}
    out = Path(out)
    with claim_dataset(
        out,
        identity,
        resume=resume,
        overwrite=overwrite,
        inputs=[source.root, *inputs],
        defer_to=defer_to,
    ):
        if resume and is_complete(out):
            return load_histories(out)
        written = _write_derived(source, out, transform, derived, tasks, H, steps, progress)
        for name, path in (extra_files or {}).items():
            write_bytes_atomic(Path(path).read_bytes(), out / name)
        return written


def _write_derived(source, out, transform, derived, tasks, H, steps, progress) -> HistoryDataset:
    horizon = source.horizon
    todo = [p for p in range(len(tasks)) if not task_done(out, p, H * steps)]

    def one(p: int) -> None:
        write_task(out, p, transform(tasks[p], source.task_histories(tasks[p])), horizon)

    if todo:  # build the shared caches (histories rows) before the threads start
        source.task_histories(tasks[todo[0]])
    # Threads: parquet reads/writes, hashing and numpy reductions release the GIL.
    with ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1)) as pool:
        for _ in tqdm(
            pool.map(one, todo),
            total=len(todo),
            desc=f"derive {derived['op']}",
            unit="task",
            disable=not progress,
        ):
            pass
    keep = ("tasks", "seed", "terminal_convention")
    meta = {k: v for k, v in source.lhf.items() if k in keep}
    meta["versions"] = library_versions()
    meta["derived_from"] = {
        **derived,
        "source": str(Path(source.root).resolve()),
        "source_fingerprint": source.fingerprint,
        "source_collect": source.lhf.get("collect")
        or (source.lhf.get("derived_from") or {}).get("source_collect"),
    }
    features = source.info["features"]
    names = {k: v["names"] for k, v in features.items() if v.get("names")}
    return finalize(
        out,
        env_id=source.env_id,
        tasks=tasks,
        histories=H,
        steps=steps,
        horizon=horizon,
        lhf_meta=meta,
        split_seed=source.lhf["split_seed"],
        feature_names=names,
    )


def derive_half(
    src: str | Path,
    out: str | Path,
    *,
    fraction: float = 0.5,
    overwrite: bool = False,
    resume: bool = False,
    progress: bool = True,
) -> HistoryDataset:
    """Write the first ``fraction`` of every history of ``src`` (whole episodes) to ``out``."""
    if not 0.0 < fraction < 1.0:
        raise UserError(f"fraction must be in (0, 1), got {fraction!r}")
    source = load_histories(src)
    horizon = source.horizon
    steps = source.lhf["steps_per_history"]
    new_steps = int(steps * fraction) // horizon * horizon  # whole episodes only
    if new_steps < horizon:
        raise UserError(
            f"{fraction:.0%} of {steps} steps is less than one episode ({horizon} steps)"
        )
    derived = {
        "op": "half",
        "fraction": fraction,
        "description": f"the first {new_steps} of the {steps} transitions of every history "
        f"({new_steps // horizon} of {steps // horizon} episodes).",
    }
    return write_derived(
        source,
        out,
        lambda task, th: th.slice_steps(new_steps),
        derived,
        steps=new_steps,
        identity={"op": "half", "fraction": fraction},
        overwrite=overwrite,
        resume=resume,
        progress=progress,
    )


#: ``lhf derive OP``: the derivations by name (``DeriveOptions.op``).
DERIVATIONS = {"half": derive_half}
