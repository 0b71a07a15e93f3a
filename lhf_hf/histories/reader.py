"""Read a learning-history dataset: ``load_histories(path)`` -> ``HistoryDataset``."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import datasets
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from datasets.table import InMemoryTable

from lhf_hf import constants as C
from lhf_hf.errors import NotFoundError, UnknownNameError, UserError
from lhf_hf.utils.hub import resolve, source_of
from lhf_hf.utils.io import read_json
from lhf_hf.utils.outputs import MARKER

from .checks import check_dataset
from .schema import TaskHistories, task_histories_from_frames

REQUIRED_FRAME_COLUMNS = (
    C.OBS,
    C.ACTION,
    C.REWARD,
    C.DONE,
    C.NEXT_OBS,
    C.INDEX,
    C.EPISODE_INDEX,
    C.TASK_INDEX,
    C.TASK_ID,
    C.HISTORY_INDEX,
)
REQUIRED_HISTORY_COLUMNS = (
    C.HISTORY_INDEX,
    C.TASK_ID,
    C.LEARNER,
    C.RETURNS,
    C.FROM_INDEX,
    C.TO_INDEX,
)


class DatasetFormatError(UserError):
    """The folder is not a (complete) learning-history dataset in our layout."""


def _is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


#: The fields the readers and checks use, with the test each must pass (a damaged file is named
#: with its field, not met later as a TypeError).
INFO_FIELDS = {
    "total_frames": _is_int,
    "total_episodes": _is_int,
    "total_tasks": _is_int,
    "features": lambda x: isinstance(x, dict),
}
LHF_FIELDS = {
    "env_id": lambda x: isinstance(x, str),
    "horizon": lambda x: _is_int(x) and x > 0,
    "tasks": lambda x: isinstance(x, list) and bool(x) and all(_is_int(t) for t in x),
    "histories_per_task": _is_int,
    "steps_per_history": _is_int,
    "episodes_per_history": _is_int,
    "total_histories": _is_int,
    "split_seed": _is_int,
    "fingerprint": lambda x: isinstance(x, str),
}


def _read_object(path: Path) -> dict:
    """The JSON object in ``path``; anything else is a ``DatasetFormatError`` naming the file."""
    try:
        data = read_json(path)
    except ValueError as exc:
        raise DatasetFormatError(str(exc)) from None  # read_json's message names the file
    if not isinstance(data, dict):
        raise DatasetFormatError(f"{path} is damaged: not a JSON object")
    return data


def _check_fields(record: dict, fields: dict, where: Path) -> None:
    bad = [name for name, ok in fields.items() if not ok(record.get(name))]
    if bad:
        shown = ", ".join(f"{n}={record.get(n)!r}"[:60] for n in bad)
        raise DatasetFormatError(f"{where}: damaged or not written by lhf_hf ({shown})")


def _in_memory(table: pa.Table) -> datasets.Dataset:
    return datasets.Dataset(InMemoryTable(table))


def _missing_info_hint(root: Path) -> str:
    """Why a folder lacks ``meta/info.json``, from its manifest: removed from a finished dataset,
    or a collection that never finished (``info.json`` is written last)."""
    try:
        files = read_json(root / MARKER).get("files")
    except (OSError, ValueError, AttributeError):
        files = None
    if isinstance(files, dict):
        return (
            " (the manifest of the finished dataset lists it: it was removed since; restore it "
            "or collect again)"
            if C.INFO_PATH in files
            else ""
        )
    if (root / C.CONFIG_PATH).exists():
        return " (an unfinished collection: run it again with --resume)"
    return ""


class HistoryDataset:
    """A learning-history dataset on disk.

    ``frames`` (one row per transition), ``episodes``, ``histories`` and ``tasks`` are
    ``datasets.Dataset`` objects; ``info`` is ``meta/info.json`` (its ``lhf`` section holds the
    collection config, seeds, versions and the fingerprint).  For bulk numeric work use
    ``frame_table`` / ``task_histories``: they read the parquet files directly.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        #: Where it came from: the absolute folder, or ``org/name@commit`` when loaded from the Hub.
        self.source = str(self.root.resolve())
        info_file = self.root / C.INFO_PATH
        if not self.root.is_dir():
            raise NotFoundError(f"no dataset folder at {self.root}")
        if not info_file.exists():
            raise DatasetFormatError(
                f"{self.root} is not a learning-history dataset: {C.INFO_PATH} is missing"
                f"{_missing_info_hint(self.root)}"
            )
        self.info = _read_object(info_file)
        if self.info.get("codebase_version") != C.CODEBASE_VERSION:
            got = self.info.get("codebase_version")
            raise DatasetFormatError(
                f"{self.root}: expected a LeRobot {C.CODEBASE_VERSION} dataset, got "
                f"codebase_version={got!r} in {C.INFO_PATH}"
            )
        if "lhf" in self.info:  # layout 1: the lhf section inside info.json, sparse task_index
            raise DatasetFormatError(
                f"{self.root} is in lhf's earlier layout (the env's task number in task_index, "
                f"which LeRobot's reader cannot use): run `lhf upgrade {self.root}` once"
            )
        lhf_file = self.root / C.LHF_INFO_PATH
        if not lhf_file.exists():
            raise DatasetFormatError(
                f"{self.root} is a LeRobot dataset but not a learning-history dataset: "
                f"{C.LHF_INFO_PATH} is missing"
            )
        self.lhf = _read_object(lhf_file)
        if self.lhf.get("layout_version") != C.LAYOUT_VERSION:
            got = self.lhf.get("layout_version")
            raise DatasetFormatError(
                f"{lhf_file}: lhf layout version {got!r}, this lhf_hf reads {C.LAYOUT_VERSION}"
            )
        _check_fields(self.info, INFO_FIELDS, info_file)
        _check_fields(self.lhf, LHF_FIELDS, lhf_file)
        for rel in (C.EPISODES_PATH, C.HISTORIES_PATH, C.TASKS_PATH):
            if not (self.root / rel).exists():
                raise DatasetFormatError(f"{self.root}: {rel} is missing")
        missing = [c for c in REQUIRED_FRAME_COLUMNS if c not in self.info.get("features", {})]
        if missing:
            raise DatasetFormatError(f"{self.root}: frames lack the columns {missing}")
        try:
            cols = pq.read_schema(self.root / C.HISTORIES_PATH).names
        except (OSError, pa.ArrowException) as exc:
            raise DatasetFormatError(
                f"{self.root / C.HISTORIES_PATH} is not a readable parquet file ({exc})"
            ) from None
        missing = [c for c in REQUIRED_HISTORY_COLUMNS if c not in cols]
        if missing:
            raise DatasetFormatError(
                f"{self.root}: the histories table lacks the columns {missing}"
            )

    def __repr__(self) -> str:
        lhf = self.lhf
        return (
            f"HistoryDataset({str(self.root)!r}, env={lhf['env_id']!r}, tasks={self.info['total_tasks']}, "
            f"histories={lhf['total_histories']}, frames={self.info['total_frames']})"
        )

    # ------------------------------------------------------------------ metadata
    @property
    def env_id(self) -> str:
        return self.lhf["env_id"]

    @property
    def horizon(self) -> int:
        return int(self.lhf["horizon"])

    @property
    def fingerprint(self) -> str:
        return self.lhf["fingerprint"]

    @cached_property
    def stats(self) -> dict:
        return read_json(self.root / C.STATS_PATH)

    # ------------------------------------------------------------------ tables
    @cached_property
    def episodes(self) -> datasets.Dataset:
        return _in_memory(pq.read_table(self.root / C.EPISODES_PATH))

    @cached_property
    def histories(self) -> datasets.Dataset:
        return _in_memory(pq.read_table(self.root / C.HISTORIES_PATH))

    @cached_property
    def tasks(self) -> datasets.Dataset:
        return _in_memory(pq.read_table(self.root / C.TASKS_PATH))

    def by_history(self, column: str) -> dict:
        """history_index -> the value of ``column`` in the histories table (e.g. ``returns``)."""
        hist = self.histories.data.table
        return dict(
            zip(
                hist.column(C.HISTORY_INDEX).to_pylist(),
                hist.column(column).to_pylist(),
                strict=True,
            )
        )

    def data_files(self) -> list[Path]:
        """Data files in frame order (task position order)."""
        n = int(self.info["total_tasks"])
        files = [
            self.root
            / C.DATA_PATH.format(chunk_index=p // C.CHUNKS_SIZE, file_index=p % C.CHUNKS_SIZE)
            for p in range(n)
        ]
        absent = [f for f in files if not f.exists()]
        if absent:
            raise DatasetFormatError(
                f"{self.root}: {len(absent)} data files are missing (first: {absent[0]})"
            )
        return files

    @cached_property
    def frames(self) -> datasets.Dataset:
        """All frames as a memory-mapped ``datasets.Dataset`` (Arrow cache built on first use)."""
        files = [str(f) for f in self.data_files()]
        return datasets.load_dataset("parquet", data_files=files, split="train")

    def frame_table(self, columns: list[str] | None = None) -> pa.Table:
        """All frames (or some columns) as one Arrow table read straight from the parquet files."""
        return pa.concat_tables([pq.read_table(f, columns=columns) for f in self.data_files()])

    def task_positions(self) -> dict[int, int]:
        """task_id (the env's task number) -> position (= data file number = LeRobot task_index)."""
        tasks = self.lhf["tasks"]
        return {int(t): p for p, t in enumerate(tasks)}

    def task_frames(self, task_id: int, columns: list[str] | None = None) -> pa.Table:
        pos = self.task_positions().get(int(task_id))
        if pos is None:
            raise UnknownNameError(
                f"task {task_id} is not in {self.root} (tasks: {self.lhf['tasks'][:10]}...)"
            )
        return pq.read_table(self.data_files()[pos], columns=columns)

    def task_histories(self, task_id: int) -> TaskHistories:
        hist = pq.read_table(self.root / C.HISTORIES_PATH)
        mask = np.asarray(hist.column(C.TASK_ID).to_numpy() == int(task_id))
        return task_histories_from_frames(
            self.task_frames(task_id), hist.filter(mask), self.horizon
        )


def load_histories(path: str | Path) -> HistoryDataset:
    """Open a learning-history dataset (LeRobot v3.0 layout + lhf tables): a local folder, or a Hub
    dataset repo ``ORG/NAME[@REVISION]`` (fetched with ``snapshot_download``, then read locally)."""
    root = resolve(path, "dataset", "dataset")
    try:
        ds = HistoryDataset(root)
        problems = check_dataset(ds)  # the quick checks: footers, tables, one task's returns
        if problems:
            raise DatasetFormatError(f"{root} is inconsistent: {'; '.join(problems[:3])}")
    except DatasetFormatError as exc:
        if root == Path(path).expanduser():
            raise
        raise DatasetFormatError(
            f"the dataset repo {path} is not a learning-history dataset in the lhf layout: {exc}"
        ) from None
    ds.source = source_of(path, root)
    return ds
