"""Gridworld dynamics checked against hand-computed trajectories (paper appendix, docs/design.md 2)."""

import itertools

import numpy as np
import pytest

from lhf_hf.envs import make, make_batched
from lhf_hf.envs.gridworlds import DARK_KEY_TO_DOOR, DARKROOM, PERMUTATIONS

DOWN, UP, RIGHT, LEFT, STAY = 0, 1, 2, 3, 4  # 0=row+1, 1=row-1, 2=col+1, 3=col-1, 4=stay


def darkroom_task(row, col, size=9):
    return row * size + col


def key_door_task(key, door, size=9):
    return (key[0] * size + key[1]) * size * size + door[0] * size + door[1]


def run(core, actions):
    """Step a single-copy core through ``actions``; return (positions, rewards)."""
    core.reset()
    pos, rew = [], []
    for a in actions:
        obs, r, _ = core.step(np.array([a]))
        pos.append(tuple(obs[0]))
        rew.append(float(r[0]))
    return pos, rew


def test_moves_and_walls():
    core = make_batched("darkroom", [darkroom_task(0, 0)])
    pos, _ = run(core, [DOWN, DOWN, RIGHT, UP, LEFT, STAY])
    assert pos == [(5, 4), (6, 4), (6, 5), (5, 5), (5, 4), (5, 4)]
    # Walls: 4 steps up from (4, 4) reach row 0, further steps stay there; same for the left wall.
    pos, _ = run(core, [UP] * 6 + [LEFT] * 6)
    assert pos[3] == (0, 4) and pos[5] == (0, 4) and pos[-1] == (0, 0)
    pos, _ = run(core, [DOWN] * 6 + [RIGHT] * 6)
    assert pos[-1] == (8, 8)


def test_darkroom_reward_on_every_step_at_goal():
    core = make_batched("darkroom", [darkroom_task(4, 6)])
    _, rew = run(core, [RIGHT, RIGHT, STAY, STAY, LEFT, RIGHT] + [STAY] * 14)
    # Reward is read after the move: step 2 lands on the goal, stays pay, leaving does not.
    assert rew[:6] == [0, 1, 1, 1, 0, 1]
    assert sum(rew) == 1 + 2 + 1 + 14


def test_goal_at_start_pays_every_step():
    core = make_batched("darkroom", [darkroom_task(4, 4)])
    _, rew = run(core, [STAY] * 20)
    assert sum(rew) == 20 == core.optimal_returns[0]


def test_horizon_and_step_after_end():
    core = make_batched("darkroom", [0, 1, 2])
    core.reset()
    for t in range(20):
        _, _, done = core.step(np.zeros(3, dtype=np.int64))
        assert done.all() == (t == 19)
    with pytest.raises(RuntimeError, match="horizon"):
        core.step(np.zeros(3, dtype=np.int64))
    core.reset(mask=np.array([True, False, True]))
    assert core.elapsed_steps.tolist() == [0, 20, 0]


def test_key_then_door_one_time_rewards():
    task = key_door_task(key=(4, 6), door=(2, 6))
    core = make_batched("dark-key-to-door", [task])
    # Visit the door first (no key: nothing), then the key (+1), key again (nothing), door (+1), door again (nothing).
    actions = [UP, UP, RIGHT, RIGHT, DOWN, DOWN, UP, DOWN, UP, UP, STAY, DOWN, UP]
    pos, rew = run(core, actions)
    assert pos[3] == (2, 6) and rew[3] == 0  # on the door without the key
    assert pos[5] == (4, 6) and rew[5] == 1  # the key
    assert pos[7] == (4, 6) and rew[7] == 0  # the key again
    assert pos[9] == (2, 6) and rew[9] == 1  # the door, holding the key
    assert sum(rew) == 2  # staying on / returning to the door pays nothing more


def test_key_on_door_cell_needs_one_more_step():
    # Reference order: the door check is an `elif` of the key check.
    core = make_batched("dark-key-to-door", [key_door_task((4, 5), (4, 5))])
    _, rew = run(core, [RIGHT, STAY, STAY])
    assert rew == [1, 1, 0]
    # Key on the start cell: it is collected by the first step that stays there.
    core = make_batched("dark-key-to-door", [key_door_task((4, 4), (4, 5))])
    _, rew = run(core, [STAY, RIGHT])
    assert rew == [1, 1]


def test_key_found_is_not_observed_but_tracked():
    env = make("dark-key-to-door", key_door_task((4, 5), (0, 0)))
    obs, _ = env.reset()
    assert obs.shape == (2,) and not env.unwrapped.has_key
    obs, r, *_ = env.step(RIGHT)
    assert r == 1 and env.unwrapped.has_key and obs.tolist() == [4, 5]


@pytest.mark.parametrize("perm_index", [0, 1, 17, 64, 119])
def test_permutation_maps_actions(perm_index):
    perm = list(itertools.permutations(range(5)))[perm_index]
    assert PERMUTATIONS[perm_index].tolist() == list(perm)
    core = make_batched("darkroom-permuted", [perm_index])
    for agent_action in range(5):
        core.reset()
        obs, _, _ = core.step(np.array([agent_action]))
        base = perm[agent_action]
        expected = {DOWN: (1, 0), UP: (0, 0), RIGHT: (0, 1), LEFT: (0, 0), STAY: (0, 0)}[base]
        assert tuple(obs[0]) == expected


def test_permuted_start_and_goal():
    core = make_batched("darkroom-permuted", [0])  # identity permutation
    pos, rew = run(core, [DOWN] * 8 + [RIGHT] * 8 + [STAY] * 34)
    assert pos[0] == (1, 0) and pos[15] == (8, 8)
    assert sum(rew) == 35 == core.optimal_returns[0]


def test_optimal_return_formula_by_hand():
    # Darkroom: d = manhattan(goal, centre); return = clip(21 - d, 0, 20).
    assert DARKROOM.optimal_returns([darkroom_task(0, 0)])[0] == 13
    assert DARKROOM.optimal_returns([darkroom_task(4, 5)])[0] == 20
    assert DARKROOM.optimal_returns([darkroom_task(4, 4)])[0] == 20
    np.testing.assert_allclose(DARKROOM.optimal_returns().mean(), 16.543, atol=1e-3)
    assert DARK_KEY_TO_DOOR.optimal_returns().tolist() == [2.0] * 6561


@pytest.mark.parametrize(
    "env_id", ["darkroom", "darkroom-permuted", "darkroom-large", "dark-key-to-door"]
)
def test_oracle_reaches_optimal_return_on_every_task(env_id):
    from lhf_hf.envs.oracle import gridworld_oracle_returns

    n = make_batched(env_id, [0]).variant.num_tasks
    returns, optimal = gridworld_oracle_returns(env_id, np.arange(n))
    np.testing.assert_array_equal(returns, optimal)


def test_optimal_return_is_an_upper_bound():
    # Random policies never beat the closed-form optimum (it is the true optimum, not just the oracle's).
    rng = np.random.default_rng(0)
    for env_id in ["darkroom", "darkroom-large", "dark-key-to-door", "darkroom-permuted"]:
        core = make_batched(
            env_id, rng.integers(0, make_batched(env_id, [0]).variant.num_tasks, 500)
        )
        core.reset()
        total = np.zeros(core.num_envs)
        for _ in range(core.horizon):
            _, r, _ = core.step(rng.integers(0, 5, core.num_envs))
            total += r
        assert np.all(total <= core.optimal_returns)


@pytest.mark.parametrize("bad", [5, -1, 7])
def test_invalid_action_raises(bad):
    core = make_batched("darkroom", [0, 1])
    core.reset()
    with pytest.raises(ValueError, match="invalid action"):
        core.step(np.array([0, bad]))


def test_non_integer_or_misshaped_actions_raise():
    core = make_batched("darkroom", [0, 1])
    core.reset()
    with pytest.raises(TypeError, match="integers"):
        core.step(np.array([0.0, 1.5]))
    with pytest.raises(ValueError, match="shape"):
        core.step(np.array([0, 1, 2]))


def test_step_before_reset_raises():
    core = make_batched("darkroom", [0])
    with pytest.raises(RuntimeError, match="reset"):
        core.step(np.array([0]))


def test_bad_tasks_raise():
    with pytest.raises(IndexError, match="0..80"):
        make_batched("darkroom", [0, 81])
    with pytest.raises(IndexError, match="out of range"):
        make_batched("darkroom", [-1])
    with pytest.raises(ValueError, match="no batched core"):
        make_batched("metaworld-reach", [0])
