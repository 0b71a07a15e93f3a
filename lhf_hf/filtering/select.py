"""LHF as a ``datasets`` operation: score the histories table, resample per task, save a selection.

A *selection* is one row per selected history (``task_id``, ``history_index``, ``count``, and its
``improvement``, ``stability``, ``score``, ``probability``) plus the filter config and the source
dataset's fingerprint.  It never rewrites frames: ``apply_selection`` / ``materialize`` do that.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import datasets
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from datasets.table import InMemoryTable

from lhf_hf import constants as C
from lhf_hf.configs.filter import FilterConfig
from lhf_hf.configs.types import config_from_record
from lhf_hf.envs import get_spec
from lhf_hf.errors import NotFoundError, UserError
from lhf_hf.utils.hub import resolve
from lhf_hf.utils.io import read_json, write_json_atomic, write_parquet_atomic
from lhf_hf.utils.versions import library_versions

from .resample import resample_task
from .scores import score_arrays
from .within_task import within_task

SELECTION_FILE = "selection.parquet"
SCORES_FILE = "scores.parquet"  # every history, rejected ones included (count 0)
CONFIG_FILE = "filter_config.json"
PLOT_FILE = "selection.png"
SCORE_COLUMNS = ("improvement", "stability", "score")


def _r_max_lookup(r_max, env_id: str | None) -> dict | float:
    if isinstance(r_max, dict):
        return {int(k): float(v) for k, v in r_max.items()}
    if r_max is not None:
        return float(r_max)
    if env_id is None:
        raise UserError(
            "r_max is needed: pass r_max=... (a return, or {task: return}) or env_id=... for "
            "an env whose optimal returns are known (gridworlds)"
        )

    spec = get_spec(env_id)
    if spec.optimal_returns is None:
        raise UserError(
            f"{env_id} has no known optimal return: pass r_max (e.g. --r-max) for its scores"
        )
    return {t: float(v) for t, v in enumerate(spec.optimal_returns())}


def _score_batch(batch: pa.Table, lam: float, r_max) -> pa.Table:
    """Batched ``datasets.map`` function on Arrow batches: Improvement, Stability, U per history."""
    hist = batch.column(C.HISTORY_INDEX).to_numpy()
    tasks = batch.column(C.TASK_ID).to_numpy()
    returns = batch.column(C.RETURNS).combine_chunks()
    lengths = pa.compute.list_value_length(returns).fill_null(0).to_numpy(zero_copy_only=False)
    if np.any(lengths == 0):
        raise UserError(
            f"history {hist[int(np.argmax(lengths == 0))]}: empty list of episode returns"
        )
    if isinstance(r_max, float):
        rmax = np.full(tasks.size, r_max)
    else:
        rmax = np.array([r_max.get(int(t), np.nan) for t in tasks])
    if np.any(~np.isfinite(rmax)):
        i = int(np.argmax(~np.isfinite(rmax)))
        raise UserError(f"history {hist[i]}: no r_max for task {tasks[i]}")
    values = (
        returns.flatten().to_numpy(zero_copy_only=False).astype(np.float64)
    )  # all returns, concatenated
    offsets = returns.offsets.to_numpy()[:-1] - returns.offsets.to_numpy()[0]
    out = {k: np.zeros(hist.size) for k in SCORE_COLUMNS}
    for length in np.unique(lengths):  # histories of equal length are scored together
        rows = np.flatnonzero(lengths == length)
        r = values[offsets[rows, None] + np.arange(length)]  # (n, E)
        bad = ~np.isfinite(r).all(1)
        if bad.any():
            raise UserError(
                f"history {hist[rows[np.argmax(bad)]]}: returns contain NaN or infinite values"
            )
        s = score_arrays(r, rmax[rows], lam)
        for k in SCORE_COLUMNS:
            out[k][rows] = s[k]
    for k in SCORE_COLUMNS:
        batch = batch.append_column(k, pa.array(out[k]))
    return batch


def score_histories(
    histories: datasets.Dataset, lam: float = 1.0, r_max=None, env_id: str | None = None
) -> datasets.Dataset:
    """The histories table with ``improvement``, ``stability``, ``score`` columns (a batched map)."""
    missing = [
        c for c in (C.TASK_ID, C.HISTORY_INDEX, C.RETURNS) if c not in histories.column_names
    ]
    if missing:
        raise UserError(
            f"the histories table lacks the columns {missing} (has {histories.column_names})"
        )
    if histories.num_rows == 0:
        raise UserError("the histories table is empty")
    lookup = _r_max_lookup(r_max, env_id)
    # Arrow batches: the returns lists are read as one flat array, no per-history Python lists.
    return (
        histories.with_format("arrow")
        .map(
            _score_batch,
            batched=True,
            batch_size=4096,
            fn_kwargs={"lam": lam, "r_max": lookup},
            desc="LHF scores",
            load_from_cache_file=False,
        )
        .with_format(None)
    )


def resample_scored(scored: datasets.Dataset, config: FilterConfig) -> pa.Table:
    """Per-task resampling of a scored histories table: every history with its count (0 = rejected)."""
    t = scored.data.table if hasattr(scored.data, "table") else scored.data
    task = t.column(C.TASK_ID).to_numpy()
    score = t.column("score").to_numpy()
    counts = np.zeros(task.size, dtype=np.int64)
    prob = np.zeros(task.size)
    order = np.argsort(task, kind="stable")  # rows grouped by task, dataset order within a task
    bounds = np.flatnonzero(np.diff(task[order])) + 1
    for rows in np.split(order, bounds):
        p, c = resample_task(
            score[rows],
            int(task[rows[0]]),
            config.strategy,
            config.alpha,
            config.fraction,
            config.seed,
            config.scan_order,
        )
        prob[rows], counts[rows] = p, c
    cols = {
        C.TASK_ID: task,
        C.HISTORY_INDEX: t.column(C.HISTORY_INDEX).to_numpy(),
        "count": counts,
        **{k: t.column(k).to_numpy() for k in SCORE_COLUMNS},
        "probability": prob,
    }
    if C.LEARNER in t.column_names:
        cols[C.LEARNER] = t.column(C.LEARNER)
    return pa.table(cols)


def lhf_resample(
    histories: datasets.Dataset,
    lam: float = 1.0,
    strategy: str = "linear",
    alpha: float = 0.125,
    seed: int = 0,
    r_max=None,
    *,
    fraction: float = 0.5,
    scan_order: str = "descending",
    env_id: str | None = None,
) -> datasets.Dataset:
    """LHF on a histories table: the selection, one row per selected history with its ``count``.

    ``r_max``: a return, ``{task_id: return}``, or None with ``env_id`` (a gridworld's optimal
    returns).  Counts per task sum to the task's number of histories.
    """
    config = FilterConfig(
        strategy=strategy,
        lam=lam,
        alpha=alpha,
        fraction=fraction,
        seed=seed,
        r_max=r_max if isinstance(r_max, float | int) else None,
        scan_order=scan_order,
    )
    table = resample_scored(score_histories(histories, lam, r_max, env_id), config)
    mask = pa.compute.greater(table.column("count"), 0)
    return datasets.Dataset(InMemoryTable(table.filter(mask)))


@dataclass
class Selection:
    """A filter result: every history's scores and count, the config and the source's provenance."""

    table: pa.Table  # all histories, count 0 = rejected
    config: FilterConfig
    source: dict

    @property
    def selected(self) -> datasets.Dataset:
        """One row per selected history (count >= 1)."""
        return datasets.Dataset(
            InMemoryTable(self.table.filter(pa.compute.greater(self.table.column("count"), 0)))
        )

    def counts(self) -> dict[int, int]:
        """history_index -> count, for every history of the source (0 = rejected)."""
        return dict(
            zip(
                self.table.column(C.HISTORY_INDEX).to_pylist(),
                self.table.column("count").to_pylist(),
                strict=True,
            )
        )

    def summary(self, returns: dict[int, list[float]] | None = None) -> dict:
        t = self.table
        counts = t.column("count").to_numpy()
        out = {
            "histories": int(t.num_rows),
            "selected_unique": int((counts > 0).sum()),
            "rejected": int((counts == 0).sum()),
            "max_count": int(counts.max()),
        }
        if C.LEARNER in t.column_names:
            learner = np.asarray(t.column(C.LEARNER).to_pylist())
            out["share_in_source"] = {k: float(np.mean(learner == k)) for k in np.unique(learner)}
            out["share_in_selection"] = {
                k: float(counts[learner == k].sum() / counts.sum()) for k in np.unique(learner)
            }
        if returns is not None:
            mean_ret = np.array(
                [np.mean(returns[h]) for h in t.column(C.HISTORY_INDEX).to_pylist()]
            )
            out["mean_return_source"] = float(mean_ret.mean())
            out["mean_return_selection"] = float(np.average(mean_ret, weights=counts))
            out["mean_return_selected_unique"] = float(mean_ret[counts > 0].mean())
            out["mean_return_rejected"] = (
                float(mean_ret[counts == 0].mean()) if (counts == 0).any() else None
            )
            # the pooled means above mix tasks (Simpson's paradox): the same, task by task
            out["within_task"] = within_task(t.column(C.TASK_ID).to_numpy(), mean_ret, counts)
        return out

    def save(self, out: str | Path, summary: dict | None = None) -> Path:
        out = Path(out)
        sel = self.table.filter(pa.compute.greater(self.table.column("count"), 0))
        write_parquet_atomic(sel, out / SELECTION_FILE)
        write_parquet_atomic(self.table, out / SCORES_FILE)
        write_json_atomic(
            {
                "filter": self.config.to_dict(),
                "source": self.source,
                "summary": summary or self.summary(),
                "versions": library_versions(),
                "created": datetime.now(UTC).isoformat(timespec="seconds"),
            },
            out / CONFIG_FILE,
        )
        return out


def load_selection(path: str | Path) -> Selection:
    """Read a selection folder written by ``Selection.save`` / ``lhf filter``, or a Hub dataset repo
    ``ORG/NAME[@REVISION]`` that holds one (pushed with ``lhf push``)."""
    path = resolve(path, "dataset", "selection")
    for f in (SCORES_FILE, CONFIG_FILE):
        if not (path / f).exists():
            raise NotFoundError(
                f"{path} is not a selection folder: {f} is missing (made by `lhf filter`)"
            )
    meta = read_json(path / CONFIG_FILE)
    if not isinstance(meta, dict) or not isinstance(meta.get("source"), dict):
        raise UserError(
            f"{path / CONFIG_FILE} has no 'source' object: damaged or not written by `lhf filter`"
        )
    config = config_from_record(FilterConfig, meta.get("filter"), f"{path / CONFIG_FILE} 'filter'")
    return Selection(pq.read_table(path / SCORES_FILE), config, meta["source"])


def histories_fingerprint(ds) -> str:
    """sha256 of the source's histories table file (what the selection was computed from)."""
    return hashlib.sha256((Path(ds.root) / C.HISTORIES_PATH).read_bytes()).hexdigest()


def source_mismatch(ds, selection: Selection) -> list[str]:
    """Why ``selection`` does not belong to dataset ``ds`` (its frames' fingerprint, or the
    histories table it scored, differ from the recorded ones); [] when it does."""
    src = selection.source
    problems = []
    fp = src.get("fingerprint")
    if fp is not None and fp != ds.fingerprint:
        problems.append(
            f"the selection was made from the dataset with fingerprint {fp[:16]}..., not from "
            f"{ds.root} (fingerprint {ds.fingerprint[:16]}...): filter this dataset again"
        )
    hf = src.get("histories_fingerprint")
    if not problems and hf is not None and hf != histories_fingerprint(ds):
        problems.append(
            f"the histories table of {ds.root} changed since the selection scored it: "
            "filter this dataset again"
        )
    return problems


def filter_histories(ds, config: FilterConfig) -> Selection:
    """Run ``config`` on a ``HistoryDataset``; the selection records the source's provenance."""
    scored = score_histories(ds.histories, config.lam, config.r_max, ds.env_id)
    table = resample_scored(scored, config)
    source = {
        "path": getattr(ds, "source", str(Path(ds.root).resolve())),
        "env_id": ds.env_id,
        "fingerprint": ds.fingerprint,
        "histories_fingerprint": histories_fingerprint(ds),
        "total_histories": ds.lhf["total_histories"],
        "histories_per_task": ds.lhf["histories_per_task"],
    }
    return Selection(table, config, source)
