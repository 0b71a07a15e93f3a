"""In-memory form of one task's learning histories, and its frames/episodes/histories rows.

Collectors produce a ``TaskHistories`` per task; the writer turns it into Arrow tables with global
indices that depend only on the task's position in the dataset, so tasks can be written in any
order (parallel workers, resumed runs) and still give one deterministic dataset.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from lhf_hf import constants as C
from lhf_hf.errors import UserError


@dataclass
class TaskHistories:
    """All H histories of one task, each of T transitions; arrays lead with (H, T).

    obs: (H, T, *S) state the action was taken in.
    actions: (H, T) int64 (discrete) or (H, T, A) float32, the action actually *executed* (clipped).
    rewards: (H, T) float32.
    next_obs: (H, T, *S) true next state (at an episode end: the final state, not the reset state).
    dones: (H, T) bool, True at the last step of each episode.
    optimal_actions: (H, T) int64 oracle actions in ``obs`` (gridworlds) or None.
    success: (H, T) bool ``info["success"]`` after the step, or None when the env has none.
    learner: (H,) ``ppo`` / ``sac`` / ``random``.
    learner_index: (H,) which learner of the task produced each history.
    seeds: (H,) seed of that learner.
    """

    task: int
    obs: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    next_obs: np.ndarray
    dones: np.ndarray
    optimal_actions: np.ndarray | None
    success: np.ndarray | None
    learner: list[str]
    learner_index: np.ndarray
    seeds: np.ndarray

    @property
    def num_histories(self) -> int:
        return int(self.rewards.shape[0])

    @property
    def steps(self) -> int:
        return int(self.rewards.shape[1])

    def validate(self, horizon: int) -> None:
        """Raise ``ValueError`` when shapes, episode ends or values are inconsistent."""
        H, T = self.rewards.shape
        if H == 0 or T == 0:
            raise UserError(f"task {self.task}: empty histories (shape {self.rewards.shape})")
        if T % horizon:
            raise UserError(
                f"task {self.task}: {T} steps is not a multiple of the horizon {horizon}"
            )
        for name in ("obs", "actions", "next_obs", "dones", "optimal_actions", "success"):
            arr = getattr(self, name)
            if arr is not None and arr.shape[:2] != (H, T):
                raise UserError(
                    f"task {self.task}: {name} has shape {arr.shape}, expected ({H}, {T}, ...)"
                )
        if self.obs.shape != self.next_obs.shape:
            raise UserError(
                f"task {self.task}: obs {self.obs.shape} and next_obs {self.next_obs.shape} differ"
            )
        if len(self.learner) != H or self.learner_index.shape != (H,) or self.seeds.shape != (H,):
            raise UserError(f"task {self.task}: learner/learner_index/seeds must have {H} entries")
        if not np.all(np.isfinite(self.rewards)):
            raise UserError(f"task {self.task}: non-finite rewards")
        expected = np.zeros(T, dtype=bool)
        expected[horizon - 1 :: horizon] = True
        if not np.array_equal(self.dones, np.broadcast_to(expected, (H, T))):
            raise UserError(f"task {self.task}: episodes must end exactly every {horizon} steps")

    def slice_steps(self, stop: int) -> TaskHistories:
        """The first ``stop`` transitions of every history (a view)."""
        cut = lambda a: None if a is None else a[:, :stop]  # noqa: E731
        return TaskHistories(
            task=self.task,
            obs=self.obs[:, :stop],
            actions=self.actions[:, :stop],
            rewards=self.rewards[:, :stop],
            next_obs=self.next_obs[:, :stop],
            dones=self.dones[:, :stop],
            optimal_actions=cut(self.optimal_actions),
            success=cut(self.success),
            learner=list(self.learner),
            learner_index=self.learner_index,
            seeds=self.seeds,
        )

    def take(self, histories: np.ndarray) -> TaskHistories:
        """The histories at positions ``histories`` (repeats allowed), in that order."""
        idx = np.asarray(histories, dtype=np.int64)
        pick = lambda a: None if a is None else a[idx]  # noqa: E731
        return TaskHistories(
            task=self.task,
            obs=self.obs[idx],
            actions=self.actions[idx],
            rewards=self.rewards[idx],
            next_obs=self.next_obs[idx],
            dones=self.dones[idx],
            optimal_actions=pick(self.optimal_actions),
            success=pick(self.success),
            learner=[self.learner[i] for i in idx],
            learner_index=self.learner_index[idx],
            seeds=self.seeds[idx],
        )


def _column(arr: np.ndarray) -> pa.Array:
    """(N,) -> a plain array; (N, d) -> a fixed-size list array of d values per row."""
    if arr.ndim == 1:
        return pa.array(arr)
    flat = np.ascontiguousarray(arr).reshape(arr.shape[0], -1)  # (N, d)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat.reshape(-1)), flat.shape[1])


def frames_table(th: TaskHistories, position: int, horizon: int) -> pa.Table:
    """Frames of one task, ordered by (history, step); global indices from the task ``position``."""
    H, T = th.num_histories, th.steps
    N = H * T
    E = T // horizon
    base = position * N
    step = np.tile(np.arange(T, dtype=np.int64), H)  # (N,) step within the history
    hist_in_task = np.repeat(np.arange(H, dtype=np.int64), T)  # (N,)
    history_index = position * H + hist_in_task
    frame_index = step % horizon
    cols = {
        C.OBS: _column(th.obs.reshape(N, *th.obs.shape[2:])),
        C.ACTION: _column(th.actions.reshape(N, *th.actions.shape[2:])),
        C.REWARD: pa.array(th.rewards.reshape(N).astype(np.float32)),
        C.DONE: pa.array(th.dones.reshape(N)),
        C.NEXT_OBS: _column(th.next_obs.reshape(N, *th.next_obs.shape[2:])),
    }
    if th.optimal_actions is not None:
        cols[C.OPTIMAL_ACTION] = pa.array(th.optimal_actions.reshape(N).astype(np.int64))
    if th.success is not None:
        cols[C.SUCCESS] = pa.array(th.success.reshape(N))
    cols.update(
        {
            C.INDEX: pa.array(base + np.arange(N, dtype=np.int64)),
            C.FRAME_INDEX: pa.array(frame_index),
            C.EPISODE_INDEX: pa.array(history_index * E + step // horizon),
            C.TASK_INDEX: pa.array(np.full(N, position, dtype=np.int64)),
            C.TASK_ID: pa.array(np.full(N, th.task, dtype=np.int64)),
            C.HISTORY_INDEX: pa.array(history_index),
            C.TIMESTAMP: pa.array((frame_index / C.FPS).astype(np.float32)),
        }
    )
    return pa.table(cols)


#: Per-episode stats LeRobot v3.0 keeps in the episodes table (``stats/{feature}/{stat}``).
EPISODE_STAT_NAMES = ("min", "max", "mean", "std", "count")


def _episode_stats(name: str, arr: np.ndarray, n_episodes: int, horizon: int) -> dict:
    """``stats/{name}/{stat}`` columns of one feature: each row a list of the feature's d values
    (``count``: one value), as LeRobot's ``compute_episode_stats`` gives for a vector feature."""
    x = arr.reshape(n_episodes, horizon, -1)  # (episodes, horizon, d), the stored dtype
    mean = x.sum(1, dtype=np.float64) / horizon
    # E[x^2] - E[x]^2 in float64: ~4x faster than np.std here (it was most of writing a task)
    sq = np.einsum("eti,eti->ei", x, x, dtype=np.float64) / horizon
    values = {
        "min": x.min(1).astype(np.float64),
        "max": x.max(1).astype(np.float64),
        "mean": mean,
        "std": np.sqrt(np.maximum(sq - mean * mean, 0.0)),
        "count": np.full((n_episodes, 1), horizon, dtype=np.int64),
    }  # each (episodes, d) or (episodes, 1)
    out = {}
    for stat in EPISODE_STAT_NAMES:
        v = values[stat]
        offsets = np.arange(0, v.size + 1, v.shape[1], dtype=np.int32)  # (episodes + 1,)
        out[f"{C.EPISODE_STATS}/{name}/{stat}"] = pa.ListArray.from_arrays(
            pa.array(offsets), pa.array(v.reshape(-1))
        )
    return out


def episodes_table(th: TaskHistories, position: int, horizon: int) -> pa.Table:
    """One row per episode of one task: LeRobot v3.0's episode columns (the ``tasks`` strings are
    added at ``finalize``, which knows them) plus lhf's."""
    H, T = th.num_histories, th.steps
    E = T // horizon
    returns = th.rewards.reshape(H, E, horizon).sum(-1, dtype=np.float64)  # (H, E)
    history_index = position * H + np.repeat(np.arange(H, dtype=np.int64), E)  # (H*E,)
    ep_in_hist = np.tile(np.arange(E, dtype=np.int64), H)
    start = position * H * T + (history_index - position * H) * T + ep_in_hist * horizon
    cols = {
        C.EPISODE_INDEX: pa.array(history_index * E + ep_in_hist),
        C.TASK_INDEX: pa.array(np.full(H * E, position, dtype=np.int64)),
        C.TASK_ID: pa.array(np.full(H * E, th.task, dtype=np.int64)),
        C.HISTORY_INDEX: pa.array(history_index),
        C.EPISODE_IN_HISTORY: pa.array(ep_in_hist),
        C.LENGTH: pa.array(np.full(H * E, horizon, dtype=np.int64)),
        C.EPISODE_RETURN: pa.array(returns.reshape(-1).astype(np.float32)),
    }
    if th.success is not None:
        cols[C.EPISODE_SUCCESS] = pa.array(th.success.reshape(H, E, horizon).any(-1).reshape(-1))
    cols[C.FROM_INDEX] = pa.array(start)
    cols[C.TO_INDEX] = pa.array(start + horizon)
    # one data file per task (writer.data_path); the episodes table is one file
    cols[C.DATA_CHUNK] = pa.array(np.full(H * E, position // C.CHUNKS_SIZE, dtype=np.int64))
    cols[C.DATA_FILE] = pa.array(np.full(H * E, position % C.CHUNKS_SIZE, dtype=np.int64))
    cols[C.META_CHUNK] = pa.array(np.zeros(H * E, dtype=np.int64))
    cols[C.META_FILE] = pa.array(np.zeros(H * E, dtype=np.int64))
    numeric = {
        C.OBS: th.obs,
        C.ACTION: th.actions,
        C.REWARD: th.rewards,
        C.NEXT_OBS: th.next_obs,
        C.OPTIMAL_ACTION: th.optimal_actions,
    }
    for name, arr in numeric.items():
        if arr is not None:
            cols.update(_episode_stats(name, arr, H * E, horizon))
    return pa.table(cols)


def histories_table(th: TaskHistories, position: int, horizon: int) -> pa.Table:
    """One row per history of one task, with its list of episode returns (what LHF scores)."""
    H, T = th.num_histories, th.steps
    E = T // horizon
    returns = (
        th.rewards.reshape(H, E, horizon).sum(-1, dtype=np.float64).astype(np.float32)
    )  # (H, E)
    start = position * H * T + np.arange(H, dtype=np.int64) * T
    return pa.table(
        {
            C.HISTORY_INDEX: pa.array(position * H + np.arange(H, dtype=np.int64)),
            C.TASK_INDEX: pa.array(np.full(H, position, dtype=np.int64)),
            C.TASK_ID: pa.array(np.full(H, th.task, dtype=np.int64)),
            C.HISTORY_IN_TASK: pa.array(np.arange(H, dtype=np.int64)),
            C.LEARNER: pa.array(list(th.learner), type=pa.string()),
            C.LEARNER_INDEX: pa.array(th.learner_index.astype(np.int64)),
            C.SEED: pa.array(th.seeds.astype(np.int64)),
            C.NUM_EPISODES: pa.array(np.full(H, E, dtype=np.int64)),
            C.RETURNS: pa.array(list(returns), type=pa.list_(pa.float32())),
            C.FROM_INDEX: pa.array(start),
            C.TO_INDEX: pa.array(start + T),
        }
    )


def task_histories_from_frames(
    frames: pa.Table, histories: pa.Table, horizon: int
) -> TaskHistories:
    """Inverse of ``frames_table`` for one task's frames (rows ordered by history, step)."""
    hist = histories.sort_by(C.HISTORY_IN_TASK)
    H = hist.num_rows
    N = frames.num_rows
    if H == 0 or N % H:
        raise UserError(f"{N} frames cannot be split into {H} equal histories")
    T = N // H

    def arr(name: str) -> np.ndarray | None:
        if name not in frames.column_names:
            return None
        col = frames.column(name).combine_chunks()
        if pa.types.is_fixed_size_list(col.type):
            return col.flatten().to_numpy(zero_copy_only=False).reshape(H, T, col.type.list_size)
        return col.to_numpy(zero_copy_only=False).reshape(H, T)

    task = frames.column(C.TASK_ID)[0].as_py()
    return TaskHistories(
        task=task,
        obs=arr(C.OBS),
        actions=arr(C.ACTION),
        rewards=arr(C.REWARD),
        next_obs=arr(C.NEXT_OBS),
        dones=arr(C.DONE),
        optimal_actions=arr(C.OPTIMAL_ACTION),
        success=arr(C.SUCCESS),
        learner=hist.column(C.LEARNER).to_pylist(),
        learner_index=hist.column(C.LEARNER_INDEX).to_numpy(),
        seeds=hist.column(C.SEED).to_numpy(),
    )


def features(table: pa.Table, names: dict[str, list[str] | None] | None = None) -> dict:
    """LeRobot ``features`` entry (dtype, shape, names) for every column of a frames table."""
    names = names or {}
    out = {}
    for field_ in table.schema:
        t = field_.type
        if pa.types.is_fixed_size_list(t):
            dtype, shape = t.value_type, [t.list_size]
        else:
            dtype, shape = t, [1]
        dtype_name = np.dtype(dtype.to_pandas_dtype()).name  # float32, int64, bool
        out[field_.name] = {"dtype": dtype_name, "shape": shape, "names": names.get(field_.name)}
    return out
