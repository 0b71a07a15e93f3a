"""A batch of test tasks stepped in lockstep for in-context evaluation (one registry per env family).

Every task of a batch has the same horizon, so episodes start and end together: ``step`` returns
``done`` for all tasks at once and ``reset`` starts the next episode everywhere.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lhf_hf.envs import get_spec, make, make_batched


class GridworldTasks:
    """The batched numpy core (one copy per task)."""

    def __init__(self, env_id: str, tasks: list[int], split_seed: int, seed: int):
        self.core = make_batched(env_id, tasks)
        self.horizon = self.core.horizon
        self.has_success = False

    def reset(self) -> np.ndarray:
        return self.core.reset()  # (B, S)

    def step(self, actions: np.ndarray):
        """-> next states (B, S) (true final states at the horizon), rewards (B,), done (B,), success."""
        nxt, reward, done = self.core.step(actions)
        return nxt, reward, done, None


class GymTasks:
    """One gymnasium env per task (Meta-World ML1): continuous actions, clipped to the action box."""

    def __init__(self, env_id: str, tasks: list[int], split_seed: int, seed: int):
        spec = get_spec(env_id)
        self.envs = [make(env_id, t, split_seed=split_seed) for t in tasks]
        self.horizon = spec.horizon
        self.low, self.high = spec.action_space.low, spec.action_space.high
        self.seed = seed
        self.episode = 0
        self.has_success = True

    def reset(self) -> np.ndarray:
        obs = [
            env.reset(seed=self.seed + 1000 * self.episode + i)[0]
            for i, env in enumerate(self.envs)
        ]
        self.episode += 1
        return np.stack(obs).astype(np.float32)  # (B, S)

    def step(self, actions: np.ndarray):
        out = [
            env.step(np.clip(a, self.low, self.high))
            for env, a in zip(self.envs, actions, strict=True)
        ]
        nxt = np.stack([o[0] for o in out]).astype(np.float32)
        reward = np.array([o[1] for o in out], np.float32)
        done = np.array([o[2] or o[3] for o in out])
        success = np.array([bool(o[4].get("success", False)) for o in out])
        if done.any() and not done.all():
            raise RuntimeError(
                "the tasks of a batch must end their episodes together (same horizon)"
            )
        return nxt, reward, done, success


TASK_BATCHES: dict[str, Callable[..., object]] = {
    "gridworld": GridworldTasks,
    "metaworld": GymTasks,
}


def make_task_batch(env_id: str, tasks: list[int], split_seed: int, seed: int):
    return TASK_BATCHES[get_spec(env_id).family](env_id, list(tasks), split_seed, seed)
