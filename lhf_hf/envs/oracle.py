"""Oracle rollouts: a check that every environment is solvable and behaves as specified.

Gridworlds: the exact oracle (``optimal_action``) on the batched core, one episode per task; it
must reach the task's optimal return.  Meta-World: Meta-World's own scripted policy, *given the
hidden goal* (privileged; used only to show the task is solvable in 100 steps), success per task.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from .registry import get_spec, make


def gridworld_oracle_returns(env_id: str, tasks: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """One oracle episode per task on the batched core: (returns (B,), optimal returns (B,))."""
    core = get_spec(env_id).batched(tasks)
    core.reset()
    total = np.zeros(core.num_envs, dtype=np.float64)
    for _ in range(core.horizon):
        _, reward, _ = core.step(core.optimal_action())
        total += reward
    return total, core.optimal_returns.copy()


def _scripted_policy(task_name: str):
    from .metaworld_ml1 import import_metaworld  # deferred: metaworld is an optional extra

    import_metaworld()
    import metaworld.policies as policies  # deferred: the optional metaworld extra

    cls_name = "Sawyer" + "".join(w.capitalize() for w in task_name.split("-")) + "V3Policy"
    return getattr(policies, cls_name)()


def metaworld_scripted_success(
    env_id: str, tasks: Sequence[int], split_seed: int = 0
) -> np.ndarray:
    """Success (any step) of Meta-World's scripted policy with the goal revealed, per task (B,)."""
    spec = get_spec(env_id)
    policy = _scripted_policy(env_id.removeprefix("metaworld-"))
    success = np.zeros(len(tasks), dtype=bool)
    for i, task in enumerate(tasks):
        env = make(env_id, int(task), split_seed=split_seed)
        obs, _ = env.reset()
        for _ in range(spec.horizon):
            revealed = obs.astype(np.float64)
            revealed[-3:] = env.unwrapped._env._get_pos_goal()  # privileged: the hidden goal
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # "Constant(s) may be too high"
                action = policy.get_action(revealed)
            obs, _, _, truncated, info = env.step(action)
            success[i] |= info["success"]
            if truncated:
                break
        env.close()
    return success


def oracle_report(env_id: str, split_seed: int = 0, max_tasks: int | None = None) -> dict:
    """Oracle summary on the test tasks of ``env_id``'s split (all of them unless ``max_tasks``)."""
    spec = get_spec(env_id)
    _, test = spec.split(split_seed)
    tasks = test[:max_tasks] if max_tasks else test
    if spec.batched is not None and spec.has_optimal_action:
        returns, optimal = gridworld_oracle_returns(env_id, tasks)
        return {
            "env_id": env_id,
            "tasks": len(tasks),
            "oracle": "exact",
            "mean_return": float(returns.mean()),
            "mean_optimal_return": float(optimal.mean()),
            "tasks_at_optimum": int(np.sum(returns == optimal)),
        }
    success = metaworld_scripted_success(env_id, tasks, split_seed)
    return {
        "env_id": env_id,
        "tasks": len(tasks),
        "oracle": "scripted, goal revealed",
        "success_rate": float(success.mean()),
    }
