"""A batch of test tasks stepped in lockstep for in-context evaluation: the env's batched core when
its ``EnvSpec`` has one, else one gymnasium env per task.

Every task of a batch has the same horizon, so episodes start and end together: ``step`` returns
``done`` for all tasks at once and ``reset`` starts the next episode everywhere.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from lhf_hf.envs import get_spec, make, make_batched
from lhf_hf.errors import UserError


class BatchedTasks:
    """The env's batched numpy core (one copy per task)."""

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

    def imagine(self, states: np.ndarray, actions: np.ndarray):
        """True (next states (B, N, S), rewards (B, N)) of states (B, N, S) and actions (B, N)."""
        return self.core.imagine(states, actions)


class GymTasks:
    """One gymnasium env per task (Meta-World ML1, any registered env without a batched core);
    continuous actions are clipped to the action box."""

    def __init__(self, env_id: str, tasks: list[int], split_seed: int, seed: int):
        spec = get_spec(env_id)
        self.envs = [make(env_id, t, split_seed=split_seed) for t in tasks]
        self.horizon = spec.horizon
        box = isinstance(spec.action_space, gym.spaces.Box)
        self.low, self.high = (
            (spec.action_space.low, spec.action_space.high) if box else (None, None)
        )
        self.state_dtype = spec.state_space.dtype
        self.seed = seed
        self.episode = 0
        self.has_success = spec.reports_success

    def imagine(self, states, actions):
        raise UserError(
            "planning with the true dynamics needs an env with a batched core (the gridworlds)"
        )

    def reset(self) -> np.ndarray:
        # one reset seed per (episode, row): rows beyond 1000 (many tasks x rollouts) widen the
        # stride, so no row of one episode reuses another episode's seed within a rollout
        stride = max(1000, len(self.envs))
        obs = [
            env.reset(seed=self.seed + stride * self.episode + i)[0]
            for i, env in enumerate(self.envs)
        ]
        self.episode += 1
        return np.stack(obs).astype(self.state_dtype)  # (B, S)

    def step(self, actions: np.ndarray):
        if self.low is not None:
            actions = np.clip(actions, self.low, self.high)
        out = [env.step(a) for env, a in zip(self.envs, actions, strict=True)]
        nxt = np.stack([o[0] for o in out]).astype(self.state_dtype)
        reward = np.array([o[1] for o in out], np.float32)
        done = np.array([o[2] or o[3] for o in out])
        success = np.array([bool(o[4].get("success", False)) for o in out])
        if done.any() and not done.all():
            raise RuntimeError(
                "the tasks of a batch must end their episodes together (same horizon)"
            )
        return nxt, reward, done, success


def make_task_batch(env_id: str, tasks: list[int], split_seed: int, seed: int):
    kind = BatchedTasks if get_spec(env_id).batched is not None else GymTasks
    return kind(env_id, list(tasks), split_seed, seed)
