"""The four gridworlds of the paper (appendix "Environmental Setup"), registered by import.

Task enumeration follows the reference DICP code so that a task index means the same thing there
and here: Darkroom goals ``[i, j]`` in row-major order; Darkroom-Permuted index ``k`` is the k-th
tuple of ``itertools.permutations(range(5))``; Key-to-Door ``[i, j, k, l]`` = key (i, j), door (k, l).
"""

from __future__ import annotations

import itertools
from functools import partial

import gymnasium as gym
import numpy as np

from .gridworld_core import NUM_ACTIONS, BatchedGridworld, GridworldVariant, TaskParams
from .gridworld_env import GridworldEnv
from .registry import EnvSpec, register, shuffled_split

#: All 120 permutations of the 5 actions, in ``itertools`` order (the reference's ``perm_idx``).
PERMUTATIONS = np.array(
    list(itertools.permutations(range(NUM_ACTIONS))), dtype=np.int64
)  # (120, 5)


def _goal_tasks(tasks: np.ndarray) -> TaskParams:
    return TaskParams(goal=tasks)


def _describe_goal(size: int, task: int) -> dict:
    return {"goal": list(divmod(int(task), size))}


def _permuted_tasks(size: int, tasks: np.ndarray) -> TaskParams:
    goal = np.full(tasks.shape, size * size - 1, dtype=np.int64)  # the opposite corner (8, 8)
    return TaskParams(goal=goal, perm=PERMUTATIONS[tasks])


def _describe_permuted(size: int, task: int) -> dict:
    return {"goal": [size - 1, size - 1], "permutation": PERMUTATIONS[int(task)].tolist()}


def _key_door_tasks(size: int, tasks: np.ndarray) -> TaskParams:
    key, door = np.divmod(tasks, size * size)
    return TaskParams(goal=door, key=key)


def _describe_key_door(size: int, task: int) -> dict:
    key, door = divmod(int(task), size * size)
    return {"key": list(divmod(key, size)), "door": list(divmod(door, size))}


DARKROOM = GridworldVariant(
    name="darkroom",
    size=9,
    horizon=20,
    start=(4, 4),
    num_tasks=81,
    train_ratio=0.9,
    task_params=_goal_tasks,
    describe_task=partial(_describe_goal, 9),
)
DARKROOM_PERMUTED = GridworldVariant(
    name="darkroom-permuted",
    size=9,
    horizon=50,
    start=(0, 0),
    num_tasks=120,
    train_ratio=0.9,
    task_params=partial(_permuted_tasks, 9),
    describe_task=partial(_describe_permuted, 9),
)
DARKROOM_LARGE = GridworldVariant(
    name="darkroom-large",
    size=15,
    horizon=50,
    start=(7, 7),
    num_tasks=225,
    train_ratio=0.9,
    task_params=_goal_tasks,
    describe_task=partial(_describe_goal, 15),
)
DARK_KEY_TO_DOOR = GridworldVariant(
    name="dark-key-to-door",
    size=9,
    horizon=50,
    start=(4, 4),
    num_tasks=81 * 81,
    train_ratio=0.95,
    task_params=partial(_key_door_tasks, 9),
    describe_task=partial(_describe_key_door, 9),
)

GRIDWORLD_VARIANTS: dict[str, GridworldVariant] = {
    v.name: v for v in (DARKROOM, DARKROOM_PERMUTED, DARKROOM_LARGE, DARK_KEY_TO_DOOR)
}

_DESCRIPTIONS = {
    "darkroom": "9x9 room, start at the centre, hidden goal; +1 per step on the goal",
    "darkroom-permuted": "9x9 room, corner to corner; each task permutes the 5 actions",
    "darkroom-large": "15x15 room, start at the centre, hidden goal; +1 per step on the goal",
    "dark-key-to-door": "9x9 room; +1 once at the hidden key, then +1 once at the hidden door",
}


def _make_gridworld(
    variant: GridworldVariant, task: int, split_seed: int, **kwargs
) -> GridworldEnv:
    del split_seed  # gridworld tasks are global; the seed only chooses the split
    return GridworldEnv(variant, task, **kwargs)


# Model context (transitions) and DICP planning depth of the reference code (docs/design.md 6, 7).
_CONTEXT_LENGTH = {"darkroom": 80}
_PLAN_HORIZON = {"darkroom": 8}
# The paper's PPO (n_steps, batch_size, n_epochs) per gridworld (docs/design.md 3).
_PPO = {
    "darkroom": (20, 50, 20),
    "darkroom-permuted": (50, 50, 20),
    "darkroom-large": (50, 50, 20),
    "dark-key-to-door": (50, 100, 10),
}


def _describe(variant: GridworldVariant, task: int, split_seed: int) -> dict:
    del split_seed  # gridworld tasks are global
    return variant.describe_task(task)


def _register(variant: GridworldVariant) -> None:
    num_train = round(variant.num_tasks * variant.train_ratio)  # reference: Python's round()
    register(
        EnvSpec(
            env_id=variant.name,
            family="gridworld",
            description=_DESCRIPTIONS[variant.name],
            horizon=variant.horizon,
            num_tasks=variant.num_tasks,
            num_train_tasks=num_train,
            state_space=gym.spaces.Box(0, variant.size - 1, shape=(2,), dtype=np.int64),
            action_space=gym.spaces.Discrete(NUM_ACTIONS),
            factory=partial(_make_gridworld, variant),
            split=partial(shuffled_split, variant.num_tasks, num_train),
            optimal_returns=variant.optimal_returns,
            context_length=_CONTEXT_LENGTH.get(variant.name, 200),
            plan_horizon=_PLAN_HORIZON.get(variant.name, 16),
            ppo=_PPO[variant.name],
            batched=partial(BatchedGridworld, variant),
            has_optimal_action=True,
            describe_task=partial(_describe, variant),
            state_names=("row", "col"),
            reward_values=(0.0, 1.0),  # the goal (and the key, the door) give 1, a step else 0
        )
    )


for _variant in GRIDWORLD_VARIANTS.values():
    _register(_variant)
