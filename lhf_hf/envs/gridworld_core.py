"""One batched numpy core for the Darkroom family and Dark Key-to-Door.

B copies of a gridworld are stepped at once, each with its own task (goal, key/door, action
permutation).  Dynamics follow the paper's appendix "Environmental Setup" and the public DICP code
(docs/design.md section 2):

* state = (row, col); 5 actions 0=row+1, 1=row-1, 2=col+1, 3=col-1, 4=stay; moves clipped at walls;
* the reward is read on the position *after* the move;
* Darkroom family: +1 on every step the agent stands on the goal;
* Dark Key-to-Door: +1 once when the agent first stands on the key, then +1 once when it stands on
  the door holding the key (the door check is an ``elif`` of the key check, as in the reference, so
  a door on the key cell needs one more step);
* an episode never ends early, only at the horizon.

Positions are kept as flat cell indices ``row * size + col`` so that a step is a handful of numpy
operations on (B,) arrays: one lookup in a precomputed transition table, one comparison for the
reward.  That keeps the per-step overhead independent of the layout and makes B = 100 ~ 1-2 us/env.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lhf_hf.errors import OutOfRangeError, UserError

#: Row/col displacement of the five base actions (docs/design.md section 2).
MOVES = np.array([[1, 0], [-1, 0], [0, 1], [0, -1], [0, 0]], dtype=np.int64)  # (5, 2)
NUM_ACTIONS = len(MOVES)
STAY = 4


@dataclass(frozen=True)
class TaskParams:
    """Per-task parameters of a batch of gridworlds, as flat cell indices.

    goal: (B,) goal cell (the door in Key-to-Door).
    key: (B,) key cell, or None when the layout has no key.
    perm: (B, 5) executed base action for each agent action, or None for the identity.
    """

    goal: np.ndarray
    key: np.ndarray | None = None
    perm: np.ndarray | None = None


@dataclass(frozen=True)
class GridworldVariant:
    """Static description of one member of the gridworld family.

    name: env id, e.g. ``darkroom``.
    size: side of the square grid.
    horizon: episode length; episodes only end here.
    start: (row, col) every episode starts from.
    num_tasks: number of tasks, enumerated 0..num_tasks-1 as in the reference code.
    train_ratio: fraction of tasks used for pretraining (``round(num_tasks * ratio)``).
    task_params: maps an int array of task indices (B,) to their ``TaskParams``.
    describe_task: readable parameters of one task, e.g. ``{"goal": [3, 5]}``.
    """

    name: str
    size: int
    horizon: int
    start: tuple[int, int]
    num_tasks: int
    train_ratio: float
    task_params: Callable[[np.ndarray], TaskParams]
    describe_task: Callable[[int], dict]

    def __post_init__(self) -> None:
        if self.size < 2:
            raise UserError(f"GridworldVariant.size must be >= 2, got {self.size!r}")
        if self.horizon < 1:
            raise UserError(f"GridworldVariant.horizon must be >= 1, got {self.horizon!r}")
        if not all(0 <= c < self.size for c in self.start):
            raise UserError(
                f"GridworldVariant.start {self.start!r} lies outside a {self.size}x{self.size} grid"
            )
        if not 0.0 < self.train_ratio < 1.0:
            raise UserError(
                f"GridworldVariant.train_ratio must be in (0, 1), got {self.train_ratio!r}"
            )

    @property
    def num_cells(self) -> int:
        return self.size * self.size

    @property
    def start_cell(self) -> int:
        return self.start[0] * self.size + self.start[1]

    def coords(self, cells: np.ndarray) -> np.ndarray:
        """Flat cell indices (...,) -> (row, col) pairs (..., 2)."""
        cells = np.asarray(cells, dtype=np.int64)
        return np.stack(np.divmod(cells, self.size), axis=-1)

    def check_tasks(self, tasks) -> np.ndarray:
        """Validate task indices and return them as an int64 array (B,)."""
        arr = np.asarray(tasks)
        if arr.ndim == 0:
            arr = arr[None]
        if arr.ndim != 1 or arr.size == 0:
            raise UserError(
                f"{self.name}: tasks must be a non-empty 1-D sequence of ints, got shape {arr.shape}"
            )
        if arr.dtype.kind not in "iu":
            raise TypeError(f"{self.name}: task indices must be integers, got dtype {arr.dtype}")
        bad = arr[(arr < 0) | (arr >= self.num_tasks)]
        if bad.size:
            raise OutOfRangeError(
                f"{self.name}: task index {int(bad[0])} out of range; valid tasks are 0..{self.num_tasks - 1}"
            )
        return arr.astype(np.int64)

    def optimal_returns(self, tasks=None) -> np.ndarray:
        """Optimal episode return of each task (float64, (B,)); all tasks when ``tasks`` is None.

        Darkroom family: the goal is reached after d = manhattan(start, goal) moves and then held,
        so the return is clip(H + 1 - d, 0, H) (d = 0 still needs one step: rewards are read after
        the move).  Key-to-Door: key after max(d(start, key), 1) steps, door after a further
        max(d(key, door), 1) steps; each reward counts if it fits in the horizon.
        """
        tasks = np.arange(self.num_tasks) if tasks is None else self.check_tasks(tasks)
        params = self.task_params(tasks)
        start = np.asarray(self.start, dtype=np.int64)
        H = self.horizon
        if params.key is None:
            d = np.abs(self.coords(params.goal) - start).sum(-1)
            return np.clip(H + 1 - d, 0, H).astype(np.float64)
        to_key = np.maximum(np.abs(self.coords(params.key) - start).sum(-1), 1)
        to_door = np.maximum(np.abs(self.coords(params.goal) - self.coords(params.key)).sum(-1), 1)
        return ((to_key <= H).astype(np.float64) + (to_key + to_door <= H)).astype(np.float64)


def _transition_table(size: int) -> np.ndarray:
    """next_cell[cell * 5 + base_action] for every cell and base action: (size*size*5,) int64."""
    rc = np.stack(np.divmod(np.arange(size * size), size), axis=-1)  # (C, 2)
    nxt = np.clip(rc[:, None, :] + MOVES[None, :, :], 0, size - 1)  # (C, 5, 2)
    return (nxt[..., 0] * size + nxt[..., 1]).reshape(-1)  # (C*5,)


def _oracle_table(size: int) -> np.ndarray:
    """base_action[target * C + cell]: rows first, then columns, then stay (docs/design.md section 2)."""
    rc = np.stack(np.divmod(np.arange(size * size), size), axis=-1)  # (C, 2)
    tgt, cur = rc[:, None, :], rc[None, :, :]  # (C, 1, 2), (1, C, 2)
    act = np.full((size * size, size * size), STAY, dtype=np.int64)  # (C_target, C_cell)
    act = np.where(cur[..., 1] > tgt[..., 1], 3, act)
    act = np.where(cur[..., 1] < tgt[..., 1], 2, act)
    act = np.where(cur[..., 0] > tgt[..., 0], 1, act)
    act = np.where(cur[..., 0] < tgt[..., 0], 0, act)
    return act.reshape(-1)


class BatchedGridworld:
    """B gridworlds of one variant stepped at once, each with its own task.

    ``step`` does not auto-reset: it returns the true next state at the horizon and the caller
    decides when to ``reset`` (collectors reset all copies together, the gymnasium wrapper on
    demand).  Stepping a copy whose episode has ended raises.
    """

    def __init__(self, variant: GridworldVariant, tasks) -> None:
        self.variant = variant
        self.tasks = variant.check_tasks(tasks)
        self.num_envs = int(self.tasks.size)
        self.horizon = variant.horizon
        params = variant.task_params(self.tasks)
        self._goal = params.goal.astype(np.int64)
        self._key = None if params.key is None else params.key.astype(np.int64)
        # perm[b, a] -> executed base action; flattened so one `take` maps a batch of actions.
        self._perm_flat = None if params.perm is None else params.perm.astype(np.int64).reshape(-1)
        self._perm_inv_flat = None
        if params.perm is not None:
            inv = np.argsort(params.perm, axis=1)  # inv[b, base] = agent action executing `base`
            self._perm_inv_flat = inv.astype(np.int64).reshape(-1)
        self._row_offset = np.arange(self.num_envs, dtype=np.int64) * NUM_ACTIONS  # (B,)
        self._next_cell = _transition_table(variant.size)
        self._oracle = _oracle_table(variant.size)
        self._coords = variant.coords(np.arange(variant.num_cells))  # (C, 2)
        self._optimal_returns = variant.optimal_returns(self.tasks)
        self._cell = np.full(self.num_envs, variant.start_cell, dtype=np.int64)
        self._t = np.zeros(self.num_envs, dtype=np.int64)
        self._has_key = np.zeros(self.num_envs, dtype=bool)
        self._door_done = np.zeros(self.num_envs, dtype=bool)
        self._needs_reset = True

    # ---------------------------------------------------------------- state
    @property
    def optimal_returns(self) -> np.ndarray:
        """(B,) optimal episode return of each copy's task."""
        return self._optimal_returns

    @property
    def cells(self) -> np.ndarray:
        """(B,) current flat cell index of each copy."""
        return self._cell

    @property
    def has_key(self) -> np.ndarray:
        """(B,) whether each copy picked up its key this episode (always False without keys)."""
        return self._has_key

    @property
    def elapsed_steps(self) -> np.ndarray:
        """(B,) steps taken in the current episode."""
        return self._t

    def observation(self) -> np.ndarray:
        """(B, 2) int64 positions (row, col)."""
        return self._coords[self._cell]

    # --------------------------------------------------------------- dynamics
    def reset(self, mask: np.ndarray | None = None) -> np.ndarray:
        """Reset all copies (or those where ``mask`` (B,) is True); return observations (B, 2)."""
        if mask is None:
            self._cell[:] = self.variant.start_cell
            self._t[:] = 0
            self._has_key[:] = False
            self._door_done[:] = False
            self._needs_reset = False
        else:
            if self._needs_reset:
                raise RuntimeError("reset() all copies once before resetting a subset")
            mask = np.asarray(mask, dtype=bool)
            if mask.shape != (self.num_envs,):
                raise UserError(f"reset mask must have shape ({self.num_envs},), got {mask.shape}")
            self._cell[mask] = self.variant.start_cell
            self._t[mask] = 0
            self._has_key[mask] = False
            self._door_done[mask] = False
        return self.observation()

    def check_actions(self, actions) -> np.ndarray:
        """Validate a batch of discrete actions (B,); invalid ones raise instead of being clipped."""
        a = np.asarray(actions)
        if a.shape != (self.num_envs,):
            raise UserError(
                f"expected {self.num_envs} actions of shape ({self.num_envs},), got shape {a.shape}"
            )
        if a.dtype.kind not in "iu":
            raise TypeError(
                f"actions must be integers in 0..{NUM_ACTIONS - 1}, got dtype {a.dtype}"
            )
        if a.min() < 0 or a.max() >= NUM_ACTIONS:
            bad = a[(a < 0) | (a >= NUM_ACTIONS)]
            raise UserError(
                f"invalid action {int(bad[0])}: actions are integers in 0..{NUM_ACTIONS - 1}"
            )
        return a.astype(np.int64, copy=False)

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Step every copy with its action.

        actions: (B,) ints in 0..4.
        Returns (next_obs (B, 2) int64, reward (B,) float32, done (B,) bool); ``done`` is True
        exactly when a copy reaches the horizon, and ``next_obs`` is then its true final state.
        """
        if self._needs_reset:
            raise RuntimeError("call reset() before step()")
        a = self.check_actions(actions)
        if self._t.max() >= self.horizon:
            raise RuntimeError(
                "an episode has already reached the horizon; reset() those copies first"
            )
        if self._perm_flat is not None:
            a = self._perm_flat[self._row_offset + a]  # (B,) executed base actions
        cell = self._next_cell[self._cell * NUM_ACTIONS + a]  # (B,)
        self._cell = cell
        if self._key is None:
            reward = (cell == self._goal).astype(np.float32)
        else:
            # Reference order: the key check first, the door check only when it fails (`elif`).
            got_key = ~self._has_key & (cell == self._key)
            got_door = self._has_key & ~self._door_done & (cell == self._goal)
            self._has_key |= got_key
            self._door_done |= got_door
            reward = got_key.astype(np.float32) + got_door
        self._t += 1
        return self._coords[cell], reward, self._t >= self.horizon

    def imagine(self, coords: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The true dynamics without stepping: from positions ``coords`` (B, N, 2) of copy b's
        task, actions (B, N) -> (next positions (B, N, 2) int64, rewards (B, N) float32).

        For planning with the environment's own model (a diagnostic of the planner).  Layouts with
        a key are refused: their reward depends on whether the key is held, which a position does
        not show.
        """
        if self._key is not None:
            raise UserError(
                f"{self.variant.name}: true dynamics from positions alone need a layout without a "
                "key (the reward depends on the key, which the state does not show)"
            )
        coords = np.asarray(coords, dtype=np.int64)
        a = np.asarray(actions, dtype=np.int64)  # (B, N)
        if self._perm_flat is not None:
            a = self._perm_flat[self._row_offset[:, None] + a]  # (B, N) executed base actions
        cell = coords[..., 0] * self.variant.size + coords[..., 1]  # (B, N)
        nxt = self._next_cell[cell * NUM_ACTIONS + a]  # (B, N)
        return self._coords[nxt], (nxt == self._goal[:, None]).astype(np.float32)

    def optimal_action(self) -> np.ndarray:
        """(B,) the oracle's action in the current state (DPT labels, docs/design.md section 2).

        Move along rows first, then columns, then stay; towards the key until it is held, then the
        door; permuted tasks map the base action back through the permutation.
        """
        target = self._goal if self._key is None else np.where(self._has_key, self._goal, self._key)
        base = self._oracle[target * self.variant.num_cells + self._cell]  # (B,)
        if self._perm_inv_flat is not None:
            return self._perm_inv_flat[self._row_offset + base]
        return base
