"""A ``gymnasium.Env`` over one copy of the batched gridworld core."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from lhf_hf.errors import UserError

from .gridworld_core import NUM_ACTIONS, BatchedGridworld, GridworldVariant


class GridworldEnv(gym.Env):
    """One gridworld task as a gymnasium environment (used by SB3 and the evaluators).

    Observation: ``(row, col)`` as int64 (2,).  Actions: ``Discrete(5)``; anything that is not an
    integer in 0..4 raises (no silent clipping).  Episodes end only at the horizon, reported as
    ``truncated=True`` with ``terminated=False`` (it is a time limit: the state does not hold the
    time).  Note: the reference DICP envs return ``terminated=truncated=True`` there, which makes
    SB3 skip the bootstrap at the horizon; collectors record which convention they used.
    """

    metadata = {"render_modes": ["ansi"]}

    def __init__(
        self, variant: GridworldVariant, task: int, render_mode: str | None = None
    ) -> None:
        if render_mode not in (None, "ansi"):
            raise UserError(f"render_mode must be None or 'ansi', got {render_mode!r}")
        self.variant = variant
        self.task = int(task)
        self.render_mode = render_mode
        self._core = BatchedGridworld(variant, [self.task])
        self.observation_space = gym.spaces.Box(0, variant.size - 1, shape=(2,), dtype=np.int64)
        self.action_space = gym.spaces.Discrete(NUM_ACTIONS)

    @property
    def horizon(self) -> int:
        return self.variant.horizon

    @property
    def optimal_return(self) -> float:
        """The task's optimal episode return (docs/design.md section 2)."""
        return float(self._core.optimal_returns[0])

    @property
    def has_key(self) -> bool:
        """Whether the key was picked up this episode (Key-to-Door; not part of the observation)."""
        return bool(self._core.has_key[0])

    def task_parameters(self) -> dict:
        """Readable parameters of this task, e.g. ``{"goal": [3, 5]}``."""
        return self.variant.describe_task(self.task)

    def optimal_action(self) -> int:
        """The oracle's action in the current state."""
        return int(self._core.optimal_action()[0])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)  # dynamics are deterministic; kept for the gymnasium contract
        obs = self._core.reset()[0]
        return obs, self._info()

    def step(self, action):
        a = np.asarray(action)
        if a.shape not in ((), (1,)):
            raise UserError(f"expected one discrete action, got shape {a.shape}")
        obs, reward, done = self._core.step(a.reshape(1))
        return obs[0], float(reward[0]), False, bool(done[0]), self._info()

    def _info(self) -> dict:
        if self._core._key is None:
            return {}
        return {"has_key": self.has_key, "success": bool(self._core._door_done[0])}

    def render(self) -> str | None:
        if self.render_mode != "ansi":
            return None
        size = self.variant.size
        grid = [["." for _ in range(size)] for _ in range(size)]
        params = self.variant.task_params(np.array([self.task]))
        if params.key is not None:
            kr, kc = divmod(int(params.key[0]), size)
            grid[kr][kc] = "K"
        gr, gc = divmod(int(params.goal[0]), size)
        grid[gr][gc] = "G" if params.key is None else "D"
        r, c = divmod(int(self._core.cells[0]), size)
        grid[r][c] = "A"
        return "\n".join(" ".join(row) for row in grid)
