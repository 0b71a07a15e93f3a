"""Meta-World ML1 tasks (paper appendix "Environmental Setup"; docs/design.md section 2).

We use the classic API, ``metaworld.ML1(name, seed)`` + ``env.set_task(task)``: the goal is hidden
from the observation and stays fixed across resets.  ``gymnasium.make('Meta-World/MT1', ...)``
shows the goal and redraws it at every reset, which is wrong for learning histories.  Episodes are
truncated at 100 steps as in the reference (the env's own limit is 500).

Task indices: 0..49 are ``ml1.train_tasks``, 50..99 are ``ml1.test_tasks``; the ML1 seed is the
split seed, so each split seed gives its own 50 + 50 goals.
"""

from __future__ import annotations

from functools import lru_cache, partial
from typing import Any

import gymnasium as gym
import numpy as np

from lhf_hf.errors import MissingExtraError, UnknownNameError, UserError

from .registry import EnvSpec, register

#: Our env id suffix -> Meta-World v3 task name (the paper's eight ML1 tasks).
ML1_TASKS = {
    "reach": "reach-v3",
    "reach-wall": "reach-wall-v3",
    "button-press": "button-press-v3",
    "basketball": "basketball-v3",
    "door-unlock": "door-unlock-v3",
    "push": "push-v3",
    "soccer": "soccer-v3",
    "hand-insert": "hand-insert-v3",
}
NUM_GOALS = 50  # metaworld's _N_GOALS per split
HORIZON = 100
OBS_DIM = 39
ACT_DIM = 4

_MISSING = (
    "Meta-World environments need the 'metaworld' extra (metaworld==3.1.1, mujoco 3.3): "
    "run  pip install 'lhf_hf[metaworld]'  (./scripts/test.sh installs it)"
)


def import_metaworld():
    """Import metaworld or raise an ImportError that says how to install it."""
    try:
        import metaworld  # deferred: the optional metaworld extra (MuJoCo)
    except ImportError as exc:  # pragma: no cover - exercised in a subprocess test
        raise MissingExtraError(_MISSING) from exc
    return metaworld


@lru_cache(maxsize=16)
def _benchmark(mw_name: str, seed: int):
    # ML1 construction builds the env 100 times to draw goals (~2 s); cache it per process.
    # Always pass a seed: seed=None would draw from numpy's global RNG (not reproducible).
    return import_metaworld().ML1(mw_name, seed=seed)


class MetaWorldML1Env(gym.Env):
    """One ML1 task (fixed hidden goal) as a gymnasium env with a 100-step horizon.

    Observations are float32 (39,).  Actions are float32 (4,) in [-1, 1]; Meta-World clips
    out-of-range actions itself, so the executed action is returned as ``info["executed_action"]``
    (the recorder logs that, not the raw sample).  Non-finite or wrongly shaped actions raise.
    ``info["success"]`` is a bool; an episode's success is any step with success.
    """

    metadata = {"render_modes": []}

    def __init__(
        self, task_name: str, task: int, split_seed: int = 0, max_episode_steps: int = HORIZON
    ) -> None:
        if task_name not in ML1_TASKS:
            raise UnknownNameError(
                f"unknown Meta-World ML1 task {task_name!r}; valid: {', '.join(ML1_TASKS)}"
            )
        if not 0 <= task < 2 * NUM_GOALS:
            raise IndexError(
                f"metaworld-{task_name}: task index {task} out of range; valid tasks are 0..{2 * NUM_GOALS - 1}"
            )
        if max_episode_steps < 1:
            raise UserError(f"max_episode_steps must be >= 1, got {max_episode_steps!r}")
        self.task_name = task_name
        self.task = int(task)
        self.split_seed = int(split_seed)
        self.horizon = int(max_episode_steps)
        mw_name = ML1_TASKS[task_name]
        ml1 = _benchmark(mw_name, self.split_seed)
        is_train = self.task < NUM_GOALS
        classes = ml1.train_classes if is_train else ml1.test_classes
        mw_task = ml1.train_tasks[self.task] if is_train else ml1.test_tasks[self.task - NUM_GOALS]
        self._env = classes[mw_name]()
        self._env.set_task(mw_task)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(OBS_DIM,), dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(ACT_DIM,), dtype=np.float32)
        self._t = 0
        self._needs_reset = True

    @property
    def goal(self) -> np.ndarray:
        """The hidden goal position (3,) of the current task (for tests and cards, not the agent)."""
        return np.array(self._env._target_pos, dtype=np.float64)

    def task_parameters(self) -> dict:
        return {
            "ml1": ML1_TASKS[self.task_name],
            "split_seed": self.split_seed,
            "split": "train" if self.task < NUM_GOALS else "test",
            "rand_vec": np.asarray(self._env._last_rand_vec).round(6).tolist(),
        }

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)  # Meta-World ignores reset seeds; the frozen task fixes the layout
        obs, info = self._env.reset()
        self._t = 0
        self._needs_reset = False
        return obs.astype(np.float32), dict(info)

    def step(self, action):
        if self._needs_reset:
            raise RuntimeError("call reset() before step() (the episode ended or never started)")
        a = np.asarray(action, dtype=np.float32)
        if a.shape != (ACT_DIM,):
            raise UserError(f"expected an action of shape ({ACT_DIM},), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise UserError(f"action contains non-finite values: {a}")
        executed = np.clip(a, -1.0, 1.0)
        obs, reward, _, _, info = self._env.step(executed)
        self._t += 1
        truncated = self._t >= self.horizon
        if truncated:
            self._needs_reset = True
        info = dict(info)
        info["success"] = bool(info.get("success", 0.0))
        info["executed_action"] = executed
        return obs.astype(np.float32), float(reward), False, truncated, info

    def close(self) -> None:
        self._env.close()


def _make(task_name: str, task: int, split_seed: int, **kwargs) -> MetaWorldML1Env:
    return MetaWorldML1Env(task_name, task, split_seed=split_seed, **kwargs)


def _describe(task: int, split_seed: int) -> dict:
    # the goal vector needs the env built: 100 Meta-World envs only for it is not worth it here
    return {"ml1_task_index": int(task), "split_seed": int(split_seed)}


def _split(seed: int) -> tuple[list[int], list[int]]:
    del seed  # the ML1 seed (passed to make) draws the goals; indices are fixed 50/50
    return list(range(NUM_GOALS)), list(range(NUM_GOALS, 2 * NUM_GOALS))


for _name in ML1_TASKS:
    register(
        EnvSpec(
            env_id=f"metaworld-{_name}",
            family="metaworld",
            description=f"Meta-World ML1 {ML1_TASKS[_name]}, hidden goal, 50 train / 50 test goals",
            horizon=HORIZON,
            num_tasks=2 * NUM_GOALS,
            num_train_tasks=NUM_GOALS,
            state_space=gym.spaces.Box(-np.inf, np.inf, shape=(OBS_DIM,), dtype=np.float32),
            action_space=gym.spaces.Box(-1.0, 1.0, shape=(ACT_DIM,), dtype=np.float32),
            factory=partial(_make, _name),
            split=_split,
            seeded_tasks=True,
            extra="metaworld",
            context_length=1000,  # (ref) ten episodes of 100 steps
            ppo=(100, 200, 20),  # docs/design.md 3
            describe_task=_describe,
            extra_packages=("metaworld", "mujoco"),
            reports_success=True,
            cost_class="metaworld-ml1",  # one model size, one MuJoCo arm: --estimate's twins
        )
    )
