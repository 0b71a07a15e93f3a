"""A new environment is one ``EnvSpec`` registered in one place: collect, train and evaluate on it
without touching any other module (everything the pipeline asks about an env is on its spec)."""

from __future__ import annotations

import json
from functools import partial

import gymnasium as gym
import numpy as np
import pytest

from lhf_hf import constants as C
from lhf_hf.configs import CollectConfig, EvalConfig, TrainConfig
from lhf_hf.envs import get_spec, list_env_ids
from lhf_hf.envs.registry import _REGISTRY, EnvSpec, register, shuffled_split

ENV_ID = "toy-corridor"
LENGTH, HORIZON = 5, 6


class Corridor(gym.Env):
    """A dark 1-D corridor: start at cell 0, +1 on every step spent on the hidden goal cell ``task``;
    actions 0 = left, 1 = stay, 2 = right; episodes end at the horizon."""

    observation_space = gym.spaces.Box(0, LENGTH - 1, shape=(1,), dtype=np.int64)
    action_space = gym.spaces.Discrete(3)

    def __init__(self, task: int, split_seed: int = 0):
        self.goal, self.t, self.pos = task, 0, 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t, self.pos = 0, 0
        return np.array([self.pos]), {}

    def step(self, action):
        self.pos = int(np.clip(self.pos + int(action) - 1, 0, LENGTH - 1))
        self.t += 1
        reward = float(self.pos == self.goal)
        return np.array([self.pos]), reward, False, self.t >= HORIZON, {}


@pytest.fixture
def toy_env():
    register(
        EnvSpec(
            env_id=ENV_ID,
            family="toy",
            description="1-D dark corridor",
            horizon=HORIZON,
            num_tasks=LENGTH,
            num_train_tasks=LENGTH - 2,
            state_space=Corridor.observation_space,
            action_space=Corridor.action_space,
            factory=Corridor,
            split=partial(shuffled_split, LENGTH, LENGTH - 2),
            context_length=2 * HORIZON,
            plan_horizon=2,
            ppo=(HORIZON, 6, 2),
            describe_task=lambda task, split_seed: {"goal": int(task)},
            state_names=("cell",),
        )
    )
    yield ENV_ID
    del _REGISTRY[ENV_ID]


@pytest.mark.slow
def test_collect_train_evaluate_a_newly_registered_env(toy_env, tmp_path):
    from lhf_hf.collection import collect
    from lhf_hf.evaluation import evaluate
    from lhf_hf.training import train

    assert toy_env in list_env_ids() and get_spec(toy_env).batched is None
    ds = collect(
        CollectConfig(toy_env, tasks="train", histories=2, steps=4 * HORIZON, workers=1),
        tmp_path / "data",
    )
    assert ds.env_id == toy_env and len(ds.histories) == 3 * 2
    tasks = ds.tasks.to_pandas()
    assert sorted(json.loads(p)["goal"] for p in tasks[C.TASK_PARAMS]) == sorted(
        get_spec(toy_env).split(0)[0]
    )
    assert ds.info["features"][C.OBS]["names"] == ["cell"]
    assert ds.lhf["collect"]["ppo"]["n_steps"] == HORIZON  # the spec's PPO preset

    out = train(
        TrainConfig(
            dataset=str(ds.root), objective="dicp", out=str(tmp_path / "m"), preset="tiny",
            max_steps=3, batch_size=4, logging_steps=1, save_steps=1000,
        )
    )  # fmt: skip
    r = evaluate(
        EvalConfig(model=str(out), out=str(tmp_path / "ev"), episodes=2, plan=True),
        progress=False,
    )
    _, test = get_spec(toy_env).split(0)
    assert r["tasks"] == list(test) and np.asarray(r["returns"]).shape == (2, 2)
    assert r["success_rate"] is None  # the spec does not report success


def test_dpt_needs_an_env_with_the_oracle_action(toy_env, tmp_path):
    from lhf_hf.envs import make_batched
    from lhf_hf.training import model_config_for

    with pytest.raises(ValueError, match="DPT needs the oracle"):
        model_config_for(
            get_spec(toy_env),
            TrainConfig(dataset="x", objective="dpt", out=str(tmp_path / "m")),
            True,
        )
    with pytest.raises(ValueError, match="no batched core"):
        make_batched(toy_env, [0])
    with pytest.raises(ValueError, match="batched core"):
        CollectConfig(toy_env, collector="batched", steps=HORIZON)
