"""Environments: the four gridworlds (one batched numpy core) and Meta-World ML1, one registry.

Public surface::

    make(env_id, task, **kwargs) -> gymnasium.Env
    make_batched(env_id, tasks) -> batched core       # envs whose spec has ``batched``
    task_split(env_id, seed=0) -> (train_tasks, test_tasks)
    split_part(env_id, part, seed=0) -> tasks of 'train' | 'test' | 'validation' | 'fit'
    list_env_ids() -> list[str]
    get_spec(env_id) -> EnvSpec
"""

from lhf_hf.errors import UserError

from . import gridworlds, metaworld_ml1  # noqa: F401  (registers the envs)
from .gridworld_core import BatchedGridworld, GridworldVariant
from .gridworld_env import GridworldEnv
from .registry import SPLIT_PARTS, EnvSpec, get_spec, list_env_ids, make, split_part, task_split


def make_batched(env_id: str, tasks) -> BatchedGridworld:
    """The env's batched core stepping one copy per entry of ``tasks`` (repeats allowed)."""
    spec = get_spec(env_id)  # unknown ids get the error that lists the valid ones
    if spec.batched is None:
        batched = [e for e in list_env_ids() if get_spec(e).batched is not None]
        raise UserError(f"{env_id!r} has no batched core; batched envs: {', '.join(batched)}")
    return spec.batched(tasks)


__all__ = [
    "BatchedGridworld",
    "EnvSpec",
    "GridworldEnv",
    "GridworldVariant",
    "SPLIT_PARTS",
    "get_spec",
    "list_env_ids",
    "make",
    "make_batched",
    "split_part",
    "task_split",
]
