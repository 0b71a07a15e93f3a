"""Frames of a selection: in memory (``apply_selection``), on disk (``materialize``), or plain
dropping at the frames level (``filter_frames``)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import datasets
import numpy as np
import pyarrow as pa
from datasets.table import InMemoryTable

from lhf_hf import constants as C
from lhf_hf.errors import UserError
from lhf_hf.histories.derive import write_derived

from .select import Selection, source_mismatch


def _check_source(ds, selection: Selection) -> None:
    for problem in source_mismatch(ds, selection):
        raise UserError(problem)


def apply_selection(ds, selection: Selection) -> datasets.Dataset:
    """The frames of the selected histories, each repeated ``count`` times, in selection order.

    Built from contiguous per-history slices of the Arrow frames (zero-copy ``slice``), never from a
    random ``select`` + ``flatten_indices``.  Frame columns keep their source values (``index``
    etc. repeat for repeated histories); ``materialize`` renumbers.
    """
    _check_source(ds, selection)
    start, stop = ds.by_history(C.FROM_INDEX), ds.by_history(C.TO_INDEX)
    frames = ds.frame_table()
    sel = selection.table
    pieces = []
    for h, c in zip(
        sel.column(C.HISTORY_INDEX).to_pylist(), sel.column("count").to_pylist(), strict=True
    ):
        piece = frames.slice(start[h], stop[h] - start[h])  # (T,) rows of one history, zero-copy
        pieces += [piece] * c
    return datasets.Dataset(InMemoryTable(pa.concat_tables(pieces)))


def filter_frames(frames: datasets.Dataset, keep_history_indices) -> datasets.Dataset:
    """Drop every frame whose history is not in ``keep_history_indices`` (a vectorised batched filter)."""
    keep = np.unique(np.asarray(list(keep_history_indices), dtype=np.int64))

    def mask(history_index):
        return np.isin(np.asarray(history_index), keep)

    return frames.filter(
        mask,
        batched=True,
        batch_size=100_000,
        input_columns=[C.HISTORY_INDEX],
        desc="filter frames",
    )


def materialize(
    ds,
    selection: Selection,
    out: str | Path,
    *,
    overwrite: bool = False,
    progress: bool = True,
    inputs: Iterable[str | Path | None] = (),
    extra_files: dict[str, Path] | None = None,
    defer_to: list | None = None,
):
    """Write the selection as a full dataset in our layout (repeated histories as their own slices).

    Every task keeps its number of histories; the card says how the dataset was derived.
    ``inputs``: folders ``out`` may not be or touch besides the source dataset (the selection's).
    ``extra_files``: copied into the dataset before its manifest (``write_derived``).
    ``defer_to``: switch together with the enclosing selection (``utils.outputs.output_folder``).
    """
    _check_source(ds, selection)
    counts = selection.counts()
    hist = ds.histories.to_pandas()

    def transform(task: int, th):
        rows = hist[hist[C.TASK_ID] == task].sort_values(C.HISTORY_IN_TASK)
        reps = np.array([counts.get(int(h), 0) for h in rows[C.HISTORY_INDEX]], dtype=np.int64)
        if reps.sum() != th.num_histories:
            raise UserError(
                f"task {task}: selection counts sum to {reps.sum()}, not {th.num_histories}"
            )
        take = np.repeat(np.arange(th.num_histories), reps)  # (H,) source history per new history
        return th.take(take)

    cfg = selection.config
    what = {
        "linear": f"LHF, linear sampling, lambda={cfg.lam}",
        "softmax": f"LHF, softmax sampling, lambda={cfg.lam}, alpha={cfg.alpha}",
        "none": "no filtering (every history once)",
        "top-fraction": f"the best {cfg.fraction:.0%} of each task by U, repeated",
    }[cfg.strategy]
    derived = {
        "op": "lhf",
        "filter": cfg.to_dict(),
        "description": f"{what} (seed {cfg.seed}); each task keeps {ds.lhf['histories_per_task']} histories, "
        "selected ones repeated by their count.",
        "summary": selection.summary(),
    }
    return write_derived(
        ds,
        out,
        transform,
        derived,
        steps=ds.lhf["steps_per_history"],
        overwrite=overwrite,
        progress=progress,
        inputs=inputs,
        identity={"op": "lhf", "filter": cfg.to_dict()},
        extra_files=extra_files,
        defer_to=defer_to,
    )
