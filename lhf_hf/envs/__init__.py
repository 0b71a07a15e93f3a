"""Environments: the four gridworlds (one batched numpy core) and Meta-World ML1, one registry.

Public surface::

    make(env_id, task, **kwargs) -> gymnasium.Env
    make_batched(env_id, tasks) -> BatchedGridworld   # gridworlds only
    task_split(env_id, seed=0) -> (train_tasks, test_tasks)
    list_env_ids() -> list[str]
    get_spec(env_id) -> EnvSpec
"""

from . import gridworlds, metaworld_ml1  # noqa: F401  (registers the envs)
from .gridworld_core import BatchedGridworld, GridworldVariant
from .gridworld_env import GridworldEnv
from .gridworlds import GRIDWORLD_VARIANTS
from .registry import EnvSpec, get_spec, list_env_ids, make, task_split


def make_batched(env_id: str, tasks) -> BatchedGridworld:
    """A ``BatchedGridworld`` stepping one copy per entry of ``tasks`` (repeats allowed)."""
    get_spec(env_id)  # unknown ids get the error that lists the valid ones
    if env_id not in GRIDWORLD_VARIANTS:
        raise ValueError(
            f"{env_id!r} has no batched core; batched envs: {', '.join(GRIDWORLD_VARIANTS)}"
        )
    return BatchedGridworld(GRIDWORLD_VARIANTS[env_id], tasks)


__all__ = [
    "BatchedGridworld",
    "EnvSpec",
    "GridworldEnv",
    "GridworldVariant",
    "get_spec",
    "list_env_ids",
    "make",
    "make_batched",
    "task_split",
]
