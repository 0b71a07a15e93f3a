"""Meta-World ML1 through the classic API: headless, hidden fixed goals, 100-step truncation."""

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip(
    "metaworld", reason="needs the metaworld extra: pip install 'lhf_hf[metaworld]'"
)

from lhf_hf.envs import get_spec, make  # noqa: E402
from lhf_hf.envs.metaworld_ml1 import ML1_TASKS  # noqa: E402

pytestmark = pytest.mark.metaworld


@pytest.mark.parametrize("name", list(ML1_TASKS))
def test_episode_truncates_at_100_and_goal_is_hidden(name):
    env = make(f"metaworld-{name}", 0)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (39,) and obs.dtype == np.float32
    assert np.all(obs[-3:] == 0), "the goal must not be observed"
    rng = np.random.default_rng(0)
    for t in range(100):
        obs, reward, terminated, truncated, info = env.step(
            rng.uniform(-1, 1, 4).astype(np.float32)
        )
        assert np.isfinite(reward) and not terminated and isinstance(info["success"], bool)
        assert truncated == (t == 99)
        assert np.all(obs[-3:] == 0)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(4, dtype=np.float32))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["reach", "push", "door-unlock"])
def test_goal_fixed_across_resets_and_different_across_tasks(name):
    env_id = f"metaworld-{name}"
    env = make(env_id, 3)
    env.reset()
    goal = env.unwrapped.goal
    for _ in range(3):
        env.step(np.ones(4, dtype=np.float32))
        env.reset()
        np.testing.assert_array_equal(env.unwrapped.goal, goal)
    goals = []
    for task in (0, 1, 50, 51):  # two train and two test goals
        e = make(env_id, task)
        e.reset()
        goals.append(e.unwrapped.goal)
    assert len({tuple(g.round(6)) for g in goals}) == 4


@pytest.mark.slow
def test_split_seed_changes_goals():
    a, b = make("metaworld-reach", 0, split_seed=0), make("metaworld-reach", 0, split_seed=1)
    a.reset(), b.reset()
    assert not np.allclose(a.unwrapped.goal, b.unwrapped.goal)
    c = make("metaworld-reach", 0, split_seed=0)
    c.reset()
    np.testing.assert_array_equal(a.unwrapped.goal, c.unwrapped.goal)


def test_executed_action_is_clipped_and_reported():
    env = make("metaworld-reach", 0)
    env.reset()
    _, _, _, _, info = env.step(np.array([2.0, -3.0, 0.5, 1.0], dtype=np.float32))
    np.testing.assert_array_equal(info["executed_action"], [1.0, -1.0, 0.5, 1.0])


def test_bad_actions_and_tasks():
    env = make("metaworld-reach", 0)
    env.reset()
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="non-finite"):
        env.step(np.array([np.nan, 0, 0, 0]))
    with pytest.raises(IndexError, match="0..99"):
        make("metaworld-reach", 100)


def test_scripted_oracle_solves_reach():
    from lhf_hf.envs.oracle import metaworld_scripted_success

    assert metaworld_scripted_success("metaworld-reach", [50, 51]).all()
    assert get_spec("metaworld-reach").horizon == 100


def test_missing_extra_gives_install_hint():
    # Simulate a machine without the extra: block the import in a fresh interpreter.
    code = (
        "import sys; sys.modules['metaworld'] = None\n"
        "from lhf_hf.envs import make\n"
        "try:\n    make('metaworld-reach', 0)\n"
        "except ImportError as e:\n    print(e)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert "pip install 'lhf_hf[metaworld]'" in out
