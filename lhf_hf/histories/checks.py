"""Consistency checks of a learning-history dataset against its own records.

``quick`` (run by every ``load_histories``): the meta files against the folder's manifest; every
data file's footer (rows and columns) against ``info.json``; the histories table (task set, histories per task, unique indices, finite returns of
the right length) and the episodes table against the info totals; and, for the first task, the
episode returns recomputed from the frames' rewards.  ``full`` (``lhf verify``, ``lhf push``) also
hashes every data file against the recorded fingerprint and recomputes the returns of every task,
and leaves the manifest to its caller, which checks every file of it (so a changed meta file is
reported once, not by both).
"""

from __future__ import annotations

import hashlib

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from lhf_hf import constants as C
from lhf_hf.utils.io import sha256_file
from lhf_hf.utils.outputs import check_manifest

#: |recomputed - recorded| tolerance of a return: float32 storage of a float64 sum.
RETURN_ATOL = 1e-3


def _footers(ds) -> list[str]:
    problems = []
    features = set(ds.info.get("features", {}))
    rows = 0
    for f in ds.data_files():
        try:
            pf = pq.ParquetFile(f)
        except (OSError, pa.ArrowException, ValueError) as exc:
            problems.append(f"{f.relative_to(ds.root)}: not a readable parquet file ({exc})")
            continue
        rows += pf.metadata.num_rows
        missing = sorted(features - set(pf.schema_arrow.names))
        if missing:
            problems.append(f"{f.relative_to(ds.root)}: lacks the frame columns {missing}")
    if not problems and rows != ds.info["total_frames"]:
        problems.append(
            f"the data files hold {rows} frames, info.json says {ds.info['total_frames']}"
        )
    return problems


def _tables(ds) -> list[str]:
    problems = []
    lhf = ds.lhf
    tasks = [int(t) for t in lhf["tasks"]]
    H = int(lhf["histories_per_task"])
    E = int(lhf["episodes_per_history"])
    try:
        hist = pq.read_table(ds.root / C.HISTORIES_PATH)
        episodes = pq.read_table(ds.root / C.EPISODES_PATH)
    except (OSError, pa.ArrowException) as exc:
        return [f"the histories or episodes table is not readable ({exc})"]
    if hist.num_rows != lhf["total_histories"] or hist.num_rows != len(tasks) * H:
        problems.append(
            f"the histories table has {hist.num_rows} rows; {C.LHF_INFO_PATH} says "
            f"{lhf['total_histories']} ({len(tasks)} tasks x {H})"
        )
    if episodes.num_rows != ds.info["total_episodes"]:
        problems.append(
            f"the episodes table has {episodes.num_rows} rows; info.json says "
            f"{ds.info['total_episodes']}"
        )
    task_id = hist.column(C.TASK_ID).to_numpy()
    found, counts = np.unique(task_id, return_counts=True)
    if sorted(found.tolist()) != sorted(tasks) or (counts != H).any():
        problems.append(
            f"the histories table's task_id values do not match the dataset's {len(tasks)} "
            f"tasks x {H} histories (found {found.tolist()[:8]}...)"
        )
    if len(np.unique(hist.column(C.HISTORY_INDEX).to_numpy())) != hist.num_rows:
        problems.append("the histories table repeats history_index values")
    returns = hist.column(C.RETURNS)
    lengths = pa.compute.list_value_length(returns).to_numpy(zero_copy_only=False)
    if (lengths != E).any():
        problems.append(f"some histories do not have {E} episode returns")
    flat = pa.compute.list_flatten(returns).to_numpy(zero_copy_only=False)
    if not np.isfinite(flat).all():
        bad = next(
            h
            for h, r in zip(
                hist.column(C.HISTORY_INDEX).to_pylist(), returns.to_pylist(), strict=True
            )
            if not np.isfinite(np.asarray(r, dtype=np.float64)).all()
        )
        problems.append(f"history {bad}: returns contain NaN or infinite values")
    ep_returns = episodes.column(C.EPISODE_RETURN).to_numpy(zero_copy_only=False)
    if not np.isfinite(ep_returns).all():
        problems.append("the episodes table holds NaN or infinite episode returns")
    return problems


def _returns_of_task(ds, hist: pa.Table, task: int) -> list[str]:
    """The recorded returns of ``task`` (in the histories table ``hist``) against the sums of its
    frames' rewards."""
    frames = ds.task_frames(task, columns=[C.REWARD, C.HISTORY_INDEX, C.TASK_INDEX, C.TASK_ID])
    if (frames.column(C.TASK_ID).to_numpy() != task).any():
        return [f"task {task}: its data file holds frames of another task_id"]
    if (frames.column(C.TASK_INDEX).to_numpy() != ds.task_positions()[task]).any():
        return [f"task {task}: its frames' task_index is not its row in {C.TASKS_PATH}"]
    rewards = frames.column(C.REWARD).to_numpy().astype(np.float64)
    if not np.isfinite(rewards).all():
        return [f"task {task}: NaN or infinite rewards in its frames"]
    H, E = int(ds.lhf["histories_per_task"]), int(ds.lhf["episodes_per_history"])
    if len(rewards) != H * E * ds.horizon:
        return [f"task {task}: {len(rewards)} frames, expected {H * E * ds.horizon}"]
    recomputed = rewards.reshape(H, E, ds.horizon).sum(-1)  # (H, E), history order of the file
    mine = hist.filter(pa.compute.equal(hist.column(C.TASK_ID), task))
    order = np.argsort(mine.column(C.HISTORY_INDEX).to_numpy())
    recorded = np.array(mine.column(C.RETURNS).to_pylist(), dtype=np.float64)[order]  # (H, E)
    if recorded.shape != recomputed.shape or not np.allclose(
        recorded, recomputed, atol=RETURN_ATOL
    ):
        return [f"task {task}: the histories table's returns are not its frames' reward sums"]
    return []


def meta_problems(ds) -> list[str]:
    """The small meta files (tables, info, stats) against the manifest recorded when the dataset
    was written: cheap enough for every load (the data files are hashed by ``lhf verify``)."""
    kind, problems = check_manifest(ds.root, prefix="meta/")
    if kind is None:
        return []  # written before manifests: the consistency checks below still run
    return [p for p in problems if not p.endswith("unfinished (its command has not ended)")]


def check_dataset(ds, full: bool = False) -> list[str]:
    """Problems of dataset ``ds`` (an empty list when it is consistent); see the module docstring.
    ``full``: the deep check, run beside a check of the whole manifest (``check_manifest``)."""
    problems = ([] if full else meta_problems(ds)) + _footers(ds) + _tables(ds)
    if problems:
        return problems
    tasks = [int(t) for t in ds.lhf["tasks"]]
    hist = pq.read_table(ds.root / C.HISTORIES_PATH)  # read once, not once per task
    for task in tasks if full else tasks[:1]:
        problems += _returns_of_task(ds, hist, task)
    if full:
        digests = "".join(sha256_file(f) for f in ds.data_files())
        if hashlib.sha256(digests.encode()).hexdigest() != ds.fingerprint:
            problems.append(
                "the data files do not hash to the recorded fingerprint (changed since written)"
            )
    return problems
