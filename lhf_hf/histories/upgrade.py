"""``lhf upgrade``: rewrite a dataset of lhf's layout 1 into the current layout, in place.

Layout 1 stored the env's task number in the frames' ``task_index`` (LeRobot's reader takes that
column as a row of ``meta/tasks.parquet`` and fails on any dataset whose tasks are not 0..n-1) and
kept lhf's metadata inside ``meta/info.json``.  Each task is read back as ``TaskHistories`` and
written again through the current writer (the same commit protocol as a collection), then
``finalize`` builds the LeRobot v3.0 meta tables.  Frames, rewards and returns are unchanged; the
data files gain columns, so the fingerprint changes (the old one is recorded under ``upgraded``).
An interrupted upgrade is finished by running it again: a data file already rewritten is read in
the new layout.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from lhf_hf import constants as C
from lhf_hf.errors import NotFoundError, UserError
from lhf_hf.utils.io import read_json
from lhf_hf.utils.outputs import output_folder

from .reader import HistoryDataset
from .schema import task_histories_from_frames
from .writer import DATASET_FILES, data_path, finalize, write_task

#: Keys of layout 1's ``info.json["lhf"]`` that ``finalize`` writes itself.
_FINALIZE_OWNS = (
    "env_id",
    "horizon",
    "histories_per_task",
    "steps_per_history",
    "episodes_per_history",
    "split_seed",
    "fingerprint",
    "total_histories",
    "layout_version",
)


def _as_current(table: pa.Table) -> pa.Table:
    """A layout-1 table (the env's task number in ``task_index``) with it under ``task_id``."""
    if C.TASK_ID in table.column_names:
        return table  # rewritten by an earlier, interrupted upgrade
    return table.rename_columns([C.TASK_ID if c == C.TASK_INDEX else c for c in table.column_names])


def upgrade(path: str | Path, echo=print) -> HistoryDataset:
    """Rewrite the layout-1 dataset at ``path`` in the current layout; returns it loaded."""
    root = Path(path)
    info_file = root / C.INFO_PATH
    if not info_file.exists():
        raise NotFoundError(f"{root} is not a learning-history dataset ({C.INFO_PATH} is missing)")
    info = read_json(info_file)
    old = info.get("lhf") if isinstance(info, dict) else None
    if not isinstance(old, dict):
        if (root / C.LHF_INFO_PATH).exists():  # scripts may run it unconditionally: not an error
            ds = HistoryDataset(root)
            echo(f"{root} is already in lhf's layout {C.LAYOUT_VERSION}: nothing to do")
            return ds
        raise UserError(f"{root}: {C.INFO_PATH} has no lhf section; not an lhf dataset")
    tasks = [int(t) for t in old["tasks"]]
    horizon = int(old["horizon"])
    with output_folder(root, "dataset", resume=True, legacy=DATASET_FILES, resumable=True):
        hist = _as_current(pq.read_table(root / C.HISTORIES_PATH))
        for p, task in enumerate(tasks):
            frames = _as_current(pq.read_table(root / data_path(p)))
            rows = hist.filter(pa.compute.equal(hist.column(C.TASK_ID), task))
            write_task(root, p, task_histories_from_frames(frames, rows, horizon), horizon)
        names = {k: f.get("names") for k, f in info["features"].items() if f.get("names")}
        meta = {k: v for k, v in old.items() if k not in _FINALIZE_OWNS}
        meta["upgraded"] = {
            "from_layout": 1,
            "fingerprint": old.get("fingerprint"),
            "at": datetime.now(UTC).isoformat(timespec="seconds"),
        }
        ds = finalize(
            root,
            env_id=old["env_id"],
            tasks=tasks,
            histories=int(old["histories_per_task"]),
            steps=int(old["steps_per_history"]),
            horizon=horizon,
            lhf_meta=meta,
            split_seed=int(old["split_seed"]),
            feature_names=names,
        )
    echo(
        f"{root}: upgraded to lhf layout {C.LAYOUT_VERSION} ({len(tasks)} tasks; selections made "
        "from it before must be made again: its fingerprint changed)"
    )
    return ds
