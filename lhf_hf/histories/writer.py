"""Write learning histories in the LeRobot v3.0 layout plus the lhf extension (docs/design.md 4).

A dataset is written task by task.  Task at position p (tasks sorted by index) goes to data file p
(``data/chunk-{p // 1000}/file-{p % 1000}.parquet``) with global indices computed from p, so tasks
may finish in any order, in any process, and a resumed run gives byte-identical tables.

Commit protocol of one task (each file written atomically):
  1. ``meta/.parts/task-P.episodes.parquet`` and ``task-P.histories.parquet``
  2. the data file
  3. ``meta/.parts/task-P.json``: sha256 and row count of the data file, partial feature stats.
A task counts as done only when 3 exists and the data file still has that checksum; anything else
(killed mid-write, truncated or edited file) is redone on ``--resume``.  ``finalize`` assembles the
meta tables, stats, info, card and plot, then removes ``meta/.parts``.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from lhf_hf import constants as C
from lhf_hf.envs import get_spec
from lhf_hf.errors import UserRuntimeError
from lhf_hf.utils.io import (
    parquet_num_rows,
    read_json,
    sha256_file,
    write_json_atomic,
    write_parquet_atomic,
)
from lhf_hf.utils.outputs import OutputError, output_folder

from .card import write_card
from .reader import load_histories
from .schema import TaskHistories, episodes_table, features, frames_table, histories_table

NUMERIC_STATS = (C.OBS, C.ACTION, C.REWARD, C.NEXT_OBS, C.OPTIMAL_ACTION)


#: ``--out`` holds something that this run must not silently reuse or replace (the policy's error).
OutputExistsError = OutputError


def data_path(position: int) -> str:
    return C.DATA_PATH.format(
        chunk_index=position // C.CHUNKS_SIZE, file_index=position % C.CHUNKS_SIZE
    )


def _part(root: Path, position: int, suffix: str) -> Path:
    return root / C.PARTS_DIR / f"task-{position:06d}.{suffix}"


def _diff(a: dict, b: dict) -> list[str]:
    keys = sorted(set(a) | set(b))
    return [f"{k}: {a.get(k)!r} -> {b.get(k)!r}" for k in keys if a.get(k) != b.get(k)]


#: Files of a dataset folder written before output markers existed (``utils.outputs``).
DATASET_FILES = (C.CONFIG_PATH, C.INFO_PATH)


@contextmanager
def claim_dataset(
    root: str | Path,
    identity: dict,
    *,
    resume: bool = False,
    overwrite: bool = False,
    inputs: Iterable[str | Path | None] = (),
    defer_to: list | None = None,
) -> Iterator[Path]:
    """Hold ``root`` for writing the dataset of config ``identity`` (``utils.outputs`` policy: a
    non-empty folder must be an lhf dataset, continued with ``resume`` or replaced with
    ``overwrite``; never an input); a resumed one must have been started with the same identity.
    ``defer_to``: switch together with an enclosing artifact (``output_folder``)."""
    root = Path(root)
    with output_folder(
        root,
        "dataset",
        overwrite=overwrite,
        resume=resume,
        inputs=inputs,
        legacy=DATASET_FILES,
        resumable=True,
        defer_to=defer_to,
    ):
        config_file = root / C.CONFIG_PATH
        if resume and config_file.exists():
            diff = _diff(read_json(config_file), identity)
            if diff:
                raise OutputExistsError(
                    f"{root} holds a collection with a different config ({'; '.join(diff)}); "
                    "use another --out, or --overwrite to replace it"
                )
        else:
            write_json_atomic(identity, config_file)
        yield root


def _partial_stats(table: pa.Table) -> dict:
    """Per-feature min/max/sum/sum of squares/count of one task (merged at finalize)."""
    out = {}
    for name in NUMERIC_STATS:
        if name not in table.column_names:
            continue
        col = table.column(name).combine_chunks()
        if pa.types.is_fixed_size_list(col.type):
            x = col.flatten().to_numpy(zero_copy_only=False).reshape(len(col), col.type.list_size)
        else:
            x = col.to_numpy(zero_copy_only=False).reshape(-1, 1)
        # one contiguous row per component: numpy's axis-0 reductions of an (N, 2) array are ~50x
        # slower than these (they were 15% of writing a task)
        xt = np.ascontiguousarray(x.T)  # (k, N)
        xf = xt.astype(np.float64, copy=False)
        out[name] = {
            "min": xt.min(1).tolist(),
            "max": xt.max(1).tolist(),
            "sum": xf.sum(1).tolist(),
            "sumsq": np.einsum("ij,ij->i", xf, xf).tolist(),  # not np.dot: BLAS threads, ~7 ms
            "count": int(x.shape[0]),
        }
    return out


def write_task(root: str | Path, position: int, th: TaskHistories, horizon: int) -> None:
    """Commit one task's histories (safe to call from worker processes: files are per task)."""
    root = Path(root)
    th.validate(horizon)
    frames = frames_table(th, position, horizon)
    write_parquet_atomic(
        episodes_table(th, position, horizon), _part(root, position, "episodes.parquet")
    )
    write_parquet_atomic(
        histories_table(th, position, horizon), _part(root, position, "histories.parquet")
    )
    digest = write_parquet_atomic(frames, root / data_path(position))
    marker = {
        "task": th.task,
        "position": position,
        "rows": frames.num_rows,
        "sha256": digest,
        "features": features(frames),
        "stats": _partial_stats(frames),
    }
    write_json_atomic(marker, _part(root, position, "json"))


def task_done(root: str | Path, position: int, expected_rows: int) -> bool:
    """True when task ``position`` was fully committed and its data file is intact."""
    root = Path(root)
    marker = _part(root, position, "json")
    try:
        meta = read_json(marker)
    except (OSError, ValueError):
        return False
    data = root / data_path(position)
    if meta.get("rows") != expected_rows or parquet_num_rows(data) != expected_rows:
        return False
    if parquet_num_rows(_part(root, position, "episodes.parquet")) is None:
        return False
    if parquet_num_rows(_part(root, position, "histories.parquet")) is None:
        return False
    return sha256_file(data) == meta.get("sha256")


def is_complete(root: str | Path) -> bool:
    return (Path(root) / C.INFO_PATH).exists()


def _merge_stats(parts: list[dict]) -> dict:
    merged: dict[str, dict] = {}
    for part in parts:
        for name, s in part.items():
            m = merged.setdefault(
                name, {"min": np.inf, "max": -np.inf, "sum": 0.0, "sumsq": 0.0, "count": 0}
            )
            m["min"] = np.minimum(m["min"], s["min"])
            m["max"] = np.maximum(m["max"], s["max"])
            m["sum"] = m["sum"] + np.asarray(s["sum"])
            m["sumsq"] = m["sumsq"] + np.asarray(s["sumsq"])
            m["count"] += s["count"]
    out = {}
    for name, m in merged.items():
        mean = m["sum"] / m["count"]
        std = np.sqrt(np.maximum(m["sumsq"] / m["count"] - mean * mean, 0.0))
        out[name] = {
            "min": np.atleast_1d(m["min"]).tolist(),
            "max": np.atleast_1d(m["max"]).tolist(),
            "mean": np.atleast_1d(mean).tolist(),
            "std": np.atleast_1d(std).tolist(),
            "count": [m["count"]],
        }
    return out


def task_string(env_id: str, params: dict) -> str:
    """The task's LeRobot ``task`` string: the env and its task parameters, e.g.
    ``darkroom goal=(3, 4)``; unique per task, since tasks differ in their parameters."""
    readable = ", ".join(f"{k}={tuple(v) if isinstance(v, list) else v}" for k, v in params.items())
    return f"{env_id} {readable}"


def _with_task_strings(episodes: pa.Table, task: str) -> pa.Table:
    strings = pa.array([[task]] * episodes.num_rows, type=pa.list_(pa.string()))
    return episodes.add_column(1, C.EPISODE_TASKS, strings)


def write_tasks_table(
    root: Path,
    env_id: str,
    tasks: list[int],
    strings: list[str],
    split_seed: int,
    train: set[int],
    validation: set[int],
) -> None:
    """``meta/tasks.parquet`` as LeRobot writes it (a pandas frame indexed by the ``task`` string,
    with the dense ``task_index``), plus lhf's columns: the env's task id, split and parameters."""
    spec = get_spec(env_id)
    frame = pd.DataFrame(
        {
            C.TASK_INDEX: np.arange(len(tasks), dtype=np.int64),
            C.TASK_ID: np.asarray(tasks, dtype=np.int64),
            C.SPLIT: [
                ("validation" if t in validation else "train") if t in train else "test"
                for t in tasks
            ],
            C.TASK_PARAMS: [json.dumps(spec.task_params(t, split_seed)) for t in tasks],
        },
        index=pd.Index(strings, name=C.TASK),
    )
    write_parquet_atomic(pa.Table.from_pandas(frame), root / C.TASKS_PATH)


def finalize(
    root: str | Path,
    *,
    env_id: str,
    tasks: list[int],
    histories: int,
    steps: int,
    horizon: int,
    lhf_meta: dict,
    split_seed: int,
    feature_names: dict | None = None,
):
    """Assemble the meta tables, stats, info, card and learning-curve plot of a fully written dataset.

    Returns the loaded ``HistoryDataset``.
    """
    root = Path(root)
    frames_per_task = histories * steps
    missing = [p for p in range(len(tasks)) if not task_done(root, p, frames_per_task)]
    if missing:
        raise UserRuntimeError(
            f"{len(missing)} of {len(tasks)} tasks are not written yet (first: task "
            f"{tasks[missing[0]]}); run the collection again with --resume"
        )
    markers = [read_json(_part(root, p, "json")) for p in range(len(tasks))]
    spec = get_spec(env_id)
    train, _ = spec.split(split_seed)
    _, validation = spec.validation_split(split_seed)
    strings = [task_string(env_id, spec.task_params(t, split_seed)) for t in tasks]
    # LeRobot v3.0: each episode names its task strings; frames name the dense task_index
    episodes = pa.concat_tables(
        [
            _with_task_strings(pq.read_table(_part(root, p, "episodes.parquet")), strings[p])
            for p in range(len(tasks))
        ]
    )
    hist = pa.concat_tables(
        [pq.read_table(_part(root, p, "histories.parquet")) for p in range(len(tasks))]
    )
    write_parquet_atomic(episodes, root / C.EPISODES_PATH)
    write_parquet_atomic(hist, root / C.HISTORIES_PATH)
    write_tasks_table(root, env_id, tasks, strings, split_seed, set(train), set(validation))
    write_json_atomic(_merge_stats([m["stats"] for m in markers]), root / C.STATS_PATH)

    fingerprint = hashlib.sha256("".join(m["sha256"] for m in markers).encode()).hexdigest()
    feats = markers[0]["features"]
    for name, names in (feature_names or {}).items():
        if name in feats:
            feats[name]["names"] = names
    total_episodes = episodes.num_rows
    # meta/info.json holds exactly LeRobot v3.0's fields (its DatasetInfo warns of any other)
    info = {
        "codebase_version": C.CODEBASE_VERSION,
        "robot_type": None,
        "total_episodes": total_episodes,
        "total_frames": len(tasks) * frames_per_task,
        "total_tasks": len(tasks),
        "chunks_size": C.CHUNKS_SIZE,
        "data_files_size_in_mb": C.DATA_FILES_SIZE_IN_MB,
        "video_files_size_in_mb": C.VIDEO_FILES_SIZE_IN_MB,
        "fps": C.FPS,
        "splits": {"train": f"0:{total_episodes}"},
        "data_path": C.DATA_PATH,
        "video_path": None,
        "features": feats,
    }
    lhf_info = {
        **lhf_meta,
        "layout_version": C.LAYOUT_VERSION,
        "env_id": env_id,
        "horizon": horizon,
        "total_histories": hist.num_rows,
        "histories_per_task": histories,
        "steps_per_history": steps,
        "episodes_per_history": steps // horizon,
        "split_seed": split_seed,
        "fingerprint": fingerprint,
        "created": lhf_meta.get("created") or datetime.now(UTC).isoformat(timespec="seconds"),
    }
    write_json_atomic(lhf_info, root / C.LHF_INFO_PATH)
    write_json_atomic(info, root / C.INFO_PATH)
    ds = load_histories(root)
    write_card(ds)
    shutil.rmtree(root / C.PARTS_DIR, ignore_errors=True)
    for stray in root.rglob(".*.tmp"):  # temporary files of writers that were killed mid-write
        stray.unlink(missing_ok=True)
    return ds
