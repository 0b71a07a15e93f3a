"""The environment registry: one ``EnvSpec`` per env id, and the public ``make``/``task_split``.

Adding an environment means registering a spec here-by-import (see ``gridworlds.py`` and
``metaworld_ml1.py``); collectors, trainers and evaluators only ever go through this module.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from lhf_hf.errors import OutOfRangeError, UnknownNameError, UserError

# Tables report run r on split seed r, for at most this many runs (the main table's AD and DPT
# cells have 10): validation tasks are never a test task of these splits (validation_split).
REPORTED_SPLITS = 10


@dataclass(frozen=True)
class EnvSpec:
    """Everything the rest of lhf_hf needs to know about one environment id.

    env_id: registry key, e.g. ``darkroom`` or ``metaworld-reach``.
    family: a label for ``lhf envs`` (``gridworld``, ``metaworld``, ...); no code branches on it: what
        differs between envs is in the fields below.
    description: one line for ``lhf envs``.
    horizon: episode length in steps (episodes end only there).
    num_tasks: number of task indices accepted by ``make``.
    num_train_tasks: size of the train part of a split (the rest are test tasks).
    state_space: the observation space (gymnasium), without building an environment.
    action_space: the action space (gymnasium).
    factory: ``factory(task, split_seed) -> gymnasium.Env``.
    split: ``split(seed) -> (train_tasks, test_tasks)``.
    optimal_returns: ``() -> (num_tasks,)`` optimal episode return per task, or None where the
        optimum is not known in closed form (Meta-World: we report success instead).
    seeded_tasks: True when the task *content* depends on the split seed (Meta-World ML1 draws its
        50 train and 50 test goals from the seed); gridworld tasks are global and only the split
        depends on the seed.
    extra: optional dependency group needed to build the env (``pip install 'lhf_hf[extra]'``).
    context_length: default model context in transitions *(ref)*: darkroom 80, the other gridworlds
        200, Meta-World 1000 (docs/design.md 6).
    plan_horizon: DICP beam-search depth: darkroom 8, Darkroom-Permuted and Dark Key-to-Door 16 *(ref*:
        grid size - 1 and 2 (grid size - 1)); Darkroom-Large 16 is ours (the reference has no
        Large; its rule would give 28) (docs/design.md 7; Meta-World plans greedily one step
        ahead and ignores it).
    ppo: the paper's PPO ``(n_steps, batch_size, n_epochs)`` for this env (docs/design.md 3).
    batched: ``batched(tasks) -> core``: a numpy core stepping one copy per task at once (``reset``,
        ``step``, ``optimal_action``; see ``BatchedGridworld``), or None.  With it the batched PPO
        collector and lockstep evaluation run on this env; without it, one gymnasium env per task.
    has_optimal_action: the env exposes the oracle's action (``env.unwrapped.optimal_action()``):
        DPT's labels and the ``action.optimal`` column are recorded.
    describe_task: ``describe_task(task, split_seed) -> dict``: the task's parameters, JSON-ready,
        for ``meta/tasks.parquet``.
    state_names: names of the state coordinates (dataset features), or None.
    extra_packages: packages of the optional extra whose versions a dataset records.
    reports_success: episodes report ``info["success"]`` (Meta-World): evaluation records success.
    cost_class: envs whose stages cost the same per unit of work (one model size, one simulator
        and step cost class) share a label, so ``lhf reproduce --estimate`` may time one by the
        other's measured rate (the Meta-World ML1 tasks); None: only its own rates.
    reward_values: the rewards one step can give when they are few (the gridworlds: 0 and 1), in
        increasing order: DICP then predicts the reward as one of these classes (cross-entropy; the
        reference's reward classifier); None: a real-valued reward, regressed (Meta-World).
    """

    env_id: str
    family: str
    description: str
    horizon: int
    num_tasks: int
    num_train_tasks: int
    state_space: gym.Space
    action_space: gym.Space
    factory: Callable[[int, int], gym.Env] = field(repr=False)
    split: Callable[[int], tuple[list[int], list[int]]] = field(repr=False)
    optimal_returns: Callable[[], np.ndarray] | None = field(default=None, repr=False)
    seeded_tasks: bool = False
    extra: str | None = None
    context_length: int = 200
    plan_horizon: int = 16
    ppo: tuple[int, int, int] = (100, 200, 20)
    batched: Callable[[Sequence[int]], Any] | None = field(default=None, repr=False)
    has_optimal_action: bool = False
    describe_task: Callable[[int, int], dict] | None = field(default=None, repr=False)
    state_names: tuple[str, ...] | None = None
    extra_packages: tuple[str, ...] = ()
    reports_success: bool = False
    cost_class: str | None = None
    reward_values: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.reward_values is not None and (
            len(self.reward_values) < 2
            or any(b <= a for a, b in zip(self.reward_values, self.reward_values[1:], strict=False))
        ):
            raise UserError(
                f"EnvSpec.reward_values must be >= 2 increasing values, got {self.reward_values!r}"
            )
        if not self.env_id or self.env_id != self.env_id.strip().lower():
            raise UserError(
                f"EnvSpec.env_id must be a non-empty lower-case id, got {self.env_id!r}"
            )
        if not self.family:
            raise UserError("EnvSpec.family must be a non-empty label")
        if len(self.ppo) != 3 or min(self.ppo) < 1:
            raise UserError(
                f"EnvSpec.ppo must be (n_steps, batch_size, n_epochs) >= 1, got {self.ppo!r}"
            )
        if self.horizon < 1:
            raise UserError(f"EnvSpec.horizon must be >= 1, got {self.horizon!r}")
        if self.context_length < 1 or self.plan_horizon < 1:
            raise UserError(
                f"EnvSpec.context_length and plan_horizon must be >= 1, got "
                f"{self.context_length!r} and {self.plan_horizon!r}"
            )
        if not 0 < self.num_train_tasks < self.num_tasks:
            raise UserError(
                f"EnvSpec.num_train_tasks must be in (0, num_tasks={self.num_tasks}), got {self.num_train_tasks!r}"
            )

    @property
    def num_test_tasks(self) -> int:
        return self.num_tasks - self.num_train_tasks

    @property
    def num_validation_tasks(self) -> int:
        """Validation tasks per split: as many as the test tasks, at most a quarter of the train
        tasks (so tuning runs still train on >= 3/4 of them)."""
        return min(self.num_test_tasks, self.num_train_tasks // 4)

    def validation_split(self, split_seed: int) -> tuple[list[int], list[int]]:
        """(fit, validation): split ``split_seed``'s train tasks less ``num_validation_tasks`` of
        them held out for tuning, and those.

        Every tuning choice (budgets, gates, weights, rollouts) is made by training on the fit
        tasks and evaluating on the validation tasks; the test tasks stay for reporting.  A table's
        run ``r`` reports on split ``r``'s test tasks, so validation tasks are drawn (seeded by the
        split) only from tasks that are a test task of no reported split (``REPORTED_SPLITS``) nor
        of this one: a choice made on them never saw a task any table reports.  The train split
        itself is unchanged, so reported runs still train on every train task.  An env with too few
        such tasks gets as many as there are (``lhf envs`` shows the count).  Seeded tasks
        (``seeded_tasks``, Meta-World) are drawn anew by each split: only the split's own test
        tasks are excluded.
        """
        train, test = self.split(split_seed)
        reported = set(test)
        if not self.seeded_tasks:  # seeded tasks (Meta-World) differ between splits: no overlap
            reported = reported.union(*(self.split(s)[1] for s in range(REPORTED_SPLITS)))
        pool = [t for t in sorted(train) if t not in reported]
        k = min(self.num_validation_tasks, len(pool))
        validation = random.Random(split_seed).sample(pool, k)
        held = set(validation)
        return [t for t in train if t not in held], validation

    @property
    def is_discrete(self) -> bool:
        return isinstance(self.action_space, gym.spaces.Discrete)

    def check_task(self, task) -> int:
        """Return ``task`` as an int, or raise a clear error when it is not a valid task index."""
        if isinstance(task, bool) or not isinstance(task, int | np.integer):
            raise TypeError(f"{self.env_id}: task must be an int index, got {task!r}")
        if not 0 <= int(task) < self.num_tasks:
            raise OutOfRangeError(
                f"{self.env_id}: task index {task} out of range; valid tasks are 0..{self.num_tasks - 1}"
            )
        return int(task)

    def task_params(self, task: int, split_seed: int) -> dict:
        """The parameters of ``task`` (``describe_task``), or its index and split seed."""
        if self.describe_task is not None:
            return self.describe_task(task, split_seed)
        return {"task_id": int(task), "split_seed": int(split_seed)}

    def summary(self) -> dict:
        """A JSON-ready row for ``lhf envs``."""
        opt = None
        if self.optimal_returns is not None:
            r = self.optimal_returns()
            opt = {"min": float(r.min()), "max": float(r.max()), "mean": round(float(r.mean()), 4)}
        return {
            "env_id": self.env_id,
            "family": self.family,
            "description": self.description,
            "horizon": self.horizon,
            "num_tasks": self.num_tasks,
            "num_train_tasks": self.num_train_tasks,
            "num_test_tasks": self.num_test_tasks,
            "num_validation_tasks": len(self.validation_split(0)[1]),
            "state_space": describe_space(self.state_space),
            "action_space": describe_space(self.action_space),
            "optimal_return": opt,
            "metric": "return" if opt is not None else "success rate",
            "seeded_tasks": self.seeded_tasks,
            "extra": self.extra,
        }


def describe_space(space: gym.Space) -> str:
    """Short readable form of a gymnasium space, e.g. ``Discrete(5)`` or ``Box(int64, (2,), [0, 8])``."""
    if isinstance(space, gym.spaces.Discrete):
        return f"Discrete({int(space.n)})"
    if isinstance(space, gym.spaces.Box):
        lo, hi = np.unique(space.low), np.unique(space.high)
        bounds = f", [{lo[0]:g}, {hi[0]:g}]" if lo.size == 1 and hi.size == 1 else ""
        return f"Box({space.dtype}, {tuple(space.shape)}{bounds})"
    return str(space)


_REGISTRY: dict[str, EnvSpec] = {}


def register(spec: EnvSpec) -> EnvSpec:
    """Add ``spec`` to the registry; ids are unique."""
    if spec.env_id in _REGISTRY:
        raise UserError(f"environment {spec.env_id!r} is already registered")
    _REGISTRY[spec.env_id] = spec
    return spec


def list_env_ids() -> list[str]:
    """All registered env ids, in registration order."""
    return list(_REGISTRY)


def get_spec(env_id: str) -> EnvSpec:
    """The ``EnvSpec`` of ``env_id``; an unknown id raises a ``KeyError`` listing the valid ones."""
    try:
        return _REGISTRY[env_id]
    except (KeyError, TypeError):
        raise UnknownNameError(
            f"unknown env id {env_id!r}; valid ids: {', '.join(_REGISTRY)}"
        ) from None


def make(env_id: str, task: int, *, split_seed: int = 0, **kwargs) -> gym.Env:
    """Build the gymnasium environment of ``task`` in ``env_id``.

    split_seed only matters for envs whose task content depends on it (``spec.seeded_tasks``,
    i.e. Meta-World ML1); gridworld task indices are global.  Extra keyword arguments are passed
    to the environment's factory (none are accepted by the built-in envs).
    """
    spec = get_spec(env_id)
    task = spec.check_task(task)
    return spec.factory(task, split_seed, **kwargs)


def task_split(env_id: str, seed: int = 0) -> tuple[list[int], list[int]]:
    """(train, test) task indices of ``env_id`` for a split seed; disjoint and deterministic."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise TypeError(f"split seed must be an int, got {seed!r}")
    return get_spec(env_id).split(int(seed))


def split_part(env_id: str, part: str, seed: int = 0) -> list[int]:
    """The task indices of one named part of split ``seed``: ``train`` or ``test`` (the split),
    ``validation`` (held-out train tasks for tuning) or ``fit`` (the train tasks without them)."""
    train, test = task_split(env_id, seed)
    if part in ("train", "test"):
        return list(train if part == "train" else test)
    if part in ("fit", "validation"):
        fit, validation = get_spec(env_id).validation_split(int(seed))
        return fit if part == "fit" else validation
    raise UserError(f"unknown split part {part!r}: use one of {', '.join(SPLIT_PARTS)}")


#: the named parts of a split (``split_part``)
SPLIT_PARTS = ("train", "test", "validation", "fit")


def shuffled_split(num_tasks: int, num_train: int, seed: int) -> tuple[list[int], list[int]]:
    """The reference split: shuffle ``range(num_tasks)`` with Python's ``random`` seeded by ``seed``
    and take the first ``num_train`` as train tasks.  ``random.Random(seed).shuffle`` draws the same
    permutation as the reference's ``random.seed(seed); random.shuffle(...)`` without touching the
    global RNG, so our splits equal the DICP code's for the same ``env_split_seed``.
    """
    order = list(range(num_tasks))
    random.Random(seed).shuffle(order)
    return order[:num_train], order[num_train:]
