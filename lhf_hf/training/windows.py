"""Training windows: numpy arrays loaded once from a history dataset, windows cut at any offset.

A window is ``K`` consecutive transitions of one learning history (docs/design.md 6).  ``WindowDataset``
indexes every (history copy, offset) pair, so drawing items uniformly draws each history with the
multiplicity an LHF selection gave it (paper Algorithm 2, "Sample (C, s_q, a_l) from D_LHF").
Items are just start rows; the collators (``collators.py``) cut the windows from the arrays with one
vectorised gather per batch instead of per-sample ``datasets`` indexing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import torch

from lhf_hf import constants as C
from lhf_hf.errors import UserError
from lhf_hf.histories.reader import DatasetFormatError


@dataclass
class HistoryArrays:
    """All frames of a dataset as numpy arrays (N rows, in index order) plus history bounds.

    states / next_states: (N, S) int16 for integer grid states, float32 otherwise.
    actions: (N,) int16 ids or (N, A) float32.  rewards: (N,) float32.  dones: (N,) bool.
    optimal_actions: (N,) int16 or None.  returns_to_go: (N,) float32, the sum of the rewards from
    this step to the end of its episode.  history_start / history_stop: (H,) row bounds;
    history_index: (H,) the dataset's history ids.
    """

    states: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    dones: np.ndarray
    next_states: np.ndarray
    optimal_actions: np.ndarray | None
    returns_to_go: np.ndarray
    history_start: np.ndarray
    history_stop: np.ndarray
    history_index: np.ndarray

    @property
    def num_histories(self) -> int:
        return len(self.history_start)

    @property
    def history_lengths(self) -> np.ndarray:
        return self.history_stop - self.history_start


def _column(table: pa.Table, name: str, dtype) -> np.ndarray:
    col = table.column(name).combine_chunks()
    if pa.types.is_fixed_size_list(col.type) or pa.types.is_list(col.type):
        width = col.type.list_size if pa.types.is_fixed_size_list(col.type) else None
        flat = col.flatten().to_numpy(zero_copy_only=False)
        arr = flat.reshape(len(col), width if width else -1)
    else:
        arr = col.to_numpy(zero_copy_only=False)
    return arr.astype(dtype, copy=False)


def returns_to_go(rewards: np.ndarray, dones: np.ndarray) -> np.ndarray:
    """(N,) sum of rewards from each step to its episode's end (episodes end where ``dones``)."""
    n = len(rewards)
    ends = np.flatnonzero(dones)
    if n and (len(ends) == 0 or ends[-1] != n - 1):
        ends = np.append(ends, n - 1)  # an unfinished last episode ends at the array's end
    csum = np.cumsum(rewards, dtype=np.float64)  # (N,)
    episode_of = np.searchsorted(ends, np.arange(n))  # (N,) index of the episode's last row
    return (csum[ends][episode_of] - csum + rewards).astype(np.float32)


def load_arrays(ds, integer_states: bool, discrete_actions: bool) -> HistoryArrays:
    """Read the frames of a ``HistoryDataset`` once into ``HistoryArrays``."""
    cols = [C.INDEX, C.OBS, C.ACTION, C.REWARD, C.DONE, C.NEXT_OBS]
    has_optimal = C.OPTIMAL_ACTION in ds.info.get("features", {})
    if has_optimal:
        cols.append(C.OPTIMAL_ACTION)
    table = ds.frame_table(cols)
    if table.num_rows == 0:
        raise DatasetFormatError(f"{ds.root}: the dataset has no frames")
    index = _column(table, C.INDEX, np.int64)
    order = None
    if np.any(np.diff(index) <= 0):
        order = np.argsort(index, kind="stable")
        index = index[order]
        if np.any(np.diff(index) == 0):
            raise DatasetFormatError(f"{ds.root}: duplicate frame indices")

    def col(name, dtype):
        arr = _column(table, name, dtype)
        return arr if order is None else arr[order]

    state_dtype = np.int16 if integer_states else np.float32
    states = col(C.OBS, state_dtype)
    next_states = col(C.NEXT_OBS, state_dtype)
    actions = col(C.ACTION, np.int16 if discrete_actions else np.float32)
    if discrete_actions and actions.ndim == 2:
        actions = actions[:, 0]
    rewards = col(C.REWARD, np.float32)
    dones = col(C.DONE, bool)
    if not np.all(np.isfinite(rewards)):
        raise DatasetFormatError(
            f"{ds.root}: {int((~np.isfinite(rewards)).sum())} rewards are NaN or infinite"
        )
    optimal = col(C.OPTIMAL_ACTION, np.int16) if has_optimal else None
    if optimal is not None and optimal.ndim == 2:
        optimal = optimal[:, 0]

    hist = ds.histories.data.table
    start_idx = hist.column(C.FROM_INDEX).to_numpy().astype(np.int64)
    stop_idx = hist.column(C.TO_INDEX).to_numpy().astype(np.int64)
    start = np.searchsorted(index, start_idx)
    stop = np.searchsorted(index, stop_idx)
    if (
        len(start) == 0
        or np.any(start >= len(index))
        or np.any(index[start] != start_idx)
        or np.any(stop - start != stop_idx - start_idx)
    ):
        raise DatasetFormatError(
            f"{ds.root}: the histories table does not match the frames (history bounds "
            f"{C.FROM_INDEX}/{C.TO_INDEX} point outside the frame indices)"
        )
    if np.any(stop <= start):
        raise DatasetFormatError(f"{ds.root}: empty histories in the histories table")
    return HistoryArrays(
        states=states,
        actions=actions,
        rewards=rewards,
        dones=dones,
        next_states=next_states,
        optimal_actions=optimal,
        returns_to_go=returns_to_go(rewards, dones),
        history_start=start,
        history_stop=stop,
        history_index=hist.column(C.HISTORY_INDEX).to_numpy().astype(np.int64),
    )


class WindowDataset(torch.utils.data.Dataset):
    """Every (history copy, offset) window of ``context_length`` transitions (with band attention:
    every training sequence, ``context_length`` = the sequence length).

    counts: (H,) multiplicity of each history (an LHF selection's counts; None = 1 each; 0 = never
    drawn).  Item ``i`` is ``{"start": row, "has_prev": bool}``: the window covers rows
    ``start .. start + K - 1`` and ``has_prev`` says whether the row before it belongs to the same
    history (False only for a window at the start of a history).
    """

    def __init__(
        self, arrays: HistoryArrays, context_length: int, counts: np.ndarray | None = None
    ):
        self.arrays = arrays
        self.context_length = int(context_length)
        lengths = arrays.history_lengths
        if self.context_length > lengths.min():
            raise UserError(
                f"a window of {self.context_length} transitions is longer than the shortest history "
                f"({int(lengths.min())} transitions): use a --context-length (with band attention, "
                f"a --sequence-length) <= {int(lengths.min())}"
            )
        counts = (
            np.ones(arrays.num_histories, np.int64)
            if counts is None
            else np.asarray(counts, np.int64)
        )
        if counts.shape != (arrays.num_histories,) or np.any(counts < 0) or counts.sum() == 0:
            raise UserError("counts must be one non-negative count per history, not all zero")
        self.windows_per_history = lengths - self.context_length + 1  # (H,)
        self.cumulative = np.cumsum(counts * self.windows_per_history)  # (H,)
        self.counts = counts

    def __len__(self) -> int:
        return int(self.cumulative[-1])

    def __getitem__(self, i: int) -> dict:
        i = int(i)
        if not 0 <= i < len(self):
            raise IndexError(i)
        h = int(np.searchsorted(self.cumulative, i, side="right"))
        r = i - (int(self.cumulative[h - 1]) if h else 0)
        offset = r % int(self.windows_per_history[h])
        return {"start": int(self.arrays.history_start[h]) + offset, "has_prev": offset > 0}
