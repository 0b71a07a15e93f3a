"""The gymnasium wrapper agrees with the batched core, step by step, for many tasks at once."""

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hypothesis import given, settings
from hypothesis import strategies as st

from lhf_hf.envs import get_spec, make, make_batched

GRIDWORLDS = ["darkroom", "darkroom-permuted", "darkroom-large", "dark-key-to-door"]


@pytest.mark.parametrize("env_id", GRIDWORLDS)
def test_wrapper_matches_batched_core(env_id):
    rng = np.random.default_rng(1)
    num_tasks = get_spec(env_id).num_tasks
    tasks = rng.choice(num_tasks, size=min(num_tasks, 40), replace=False)
    core = make_batched(env_id, tasks)
    envs = [make(env_id, int(t)) for t in tasks]
    for _episode in range(2):
        obs_core = core.reset()
        obs_env = np.stack([e.reset()[0] for e in envs])
        np.testing.assert_array_equal(obs_core, obs_env)
        for _ in range(core.horizon):
            np.testing.assert_array_equal(
                core.optimal_action(), [e.unwrapped.optimal_action() for e in envs]
            )
            actions = rng.integers(0, 5, len(tasks))
            obs_core, r_core, d_core = core.step(actions)
            steps = [e.step(int(a)) for e, a in zip(envs, actions, strict=True)]
            np.testing.assert_array_equal(obs_core, np.stack([s[0] for s in steps]))
            np.testing.assert_array_equal(r_core, [s[1] for s in steps])
            np.testing.assert_array_equal(d_core, [s[3] for s in steps])
            assert not any(s[2] for s in steps)  # never terminated, only truncated at the horizon
        assert d_core.all()


@settings(max_examples=30, deadline=None)
@given(env_id=st.sampled_from(GRIDWORLDS), data=st.data())
def test_oracle_in_wrapper_reaches_optimal_return(env_id, data):
    task = data.draw(st.integers(0, get_spec(env_id).num_tasks - 1))
    env = make(env_id, task)
    env.reset()
    total, truncated = 0.0, False
    while not truncated:
        _, r, terminated, truncated, _ = env.step(env.unwrapped.optimal_action())
        assert not terminated
        total += r
    assert total == env.unwrapped.optimal_return


@pytest.mark.parametrize("env_id", GRIDWORLDS)
def test_gymnasium_env_checker(env_id):
    check_env(make(env_id, 3), skip_render_check=True)


def test_invalid_actions_in_wrapper():
    env = make("darkroom", 0)
    env.reset()
    for bad in (5, -1):
        with pytest.raises(ValueError, match="invalid action"):
            env.step(bad)
    with pytest.raises(TypeError):
        env.step(1.5)
    with pytest.raises(ValueError, match="one discrete action"):
        env.step([1, 2])
    # numpy scalars and 1-element arrays (what SB3 passes) are fine
    env.step(np.int64(2))
    env.step(np.array([2]))


def test_render_ansi():
    env = make("dark-key-to-door", (4 * 9 + 6) * 81 + 0, render_mode="ansi")
    env.reset()
    lines = env.render().splitlines()
    assert lines[4].split()[4] == "A" and lines[4].split()[6] == "K" and lines[0].split()[0] == "D"
