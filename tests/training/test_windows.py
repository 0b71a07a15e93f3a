"""Windows and collators: by hand on a toy history, and against a real collected dataset."""

from __future__ import annotations

import numpy as np
import pytest

from lhf_hf import constants as C
from lhf_hf.modeling import icrl_config
from lhf_hf.training import HistoryArrays, WindowDataset, load_arrays, make_collator, returns_to_go


def toy_arrays() -> HistoryArrays:
    """Two histories of 6 steps, episodes of 3 steps (2 per history)."""
    states = np.array([[0, 0], [0, 1], [0, 2], [1, 0], [1, 1], [1, 2]] * 2, np.int16)
    next_states = np.array([[0, 1], [0, 2], [8, 8], [1, 1], [1, 2], [7, 7]] * 2, np.int16)
    actions = np.array([0, 1, 2, 3, 4, 0] * 2, np.int16)
    rewards = np.array([0, 0, 1, 0, 1, 1] * 2, np.float32)
    dones = np.array([0, 0, 1, 0, 0, 1] * 2, bool)
    return HistoryArrays(
        states=states,
        actions=actions,
        rewards=rewards,
        dones=dones,
        next_states=next_states,
        optimal_actions=np.array([4, 3, 2, 1, 0, 4] * 2, np.int16),
        returns_to_go=returns_to_go(rewards, dones),
        history_start=np.array([0, 6]),
        history_stop=np.array([6, 12]),
        history_index=np.array([10, 11]),
    )


def toy_config(objective="ad", **kw):
    return icrl_config(
        "tiny", objective=objective, state_dim=2, state_bins=9, action_dim=5, context_length=3, **kw
    )


def test_returns_to_go_by_hand():
    r = np.array([0, 0, 1, 0, 1, 1, 2], np.float32)
    d = np.array([0, 0, 1, 0, 0, 1, 0], bool)  # the last episode is unfinished
    np.testing.assert_array_equal(returns_to_go(r, d), [1, 1, 1, 2, 2, 1, 2])


def test_window_dataset_counts_every_history_copy():
    arrays = toy_arrays()
    ds = WindowDataset(arrays, 3, counts=np.array([2, 1]))
    assert len(ds) == 3 * 4  # (2 + 1) copies x (6 - 3 + 1) offsets
    starts = [ds[i]["start"] for i in range(len(ds))]
    assert starts == [0, 1, 2, 3] * 2 + [6, 7, 8, 9]
    assert [ds[i]["has_prev"] for i in range(4)] == [False, True, True, True]
    only_second = WindowDataset(arrays, 3, counts=np.array([0, 1]))
    assert [only_second[i]["start"] for i in range(len(only_second))] == [6, 7, 8, 9]
    with pytest.raises(IndexError):
        ds[len(ds)]


@pytest.mark.parametrize(
    "counts, match",
    [([1], "one non-negative count"), ([-1, 2], "non-negative"), ([0, 0], "not all zero")],
)
def test_window_dataset_rejects_bad_counts(counts, match):
    with pytest.raises(ValueError, match=match):
        WindowDataset(toy_arrays(), 3, counts=np.array(counts))


def test_context_longer_than_histories_is_an_error():
    with pytest.raises(ValueError, match="longer than the shortest history"):
        WindowDataset(toy_arrays(), 7)


def test_ad_collator_by_hand():
    arrays = toy_arrays()
    batch = make_collator(arrays, toy_config())(
        [{"start": 1, "has_prev": True}, {"start": 6, "has_prev": False}]
    )
    assert set(batch) == {
        "states",
        "prev_states",
        "prev_actions",
        "prev_rewards",
        "prev_dones",
        "has_prev",
        "label_mask",
        "action_labels",
    }
    # window 0: rows 1, 2, 3; the previous steps are rows 0, 1, 2
    np.testing.assert_array_equal(batch["states"][0].numpy(), [[0, 1], [0, 2], [1, 0]])
    np.testing.assert_array_equal(batch["prev_states"][0].numpy(), [[0, 0], [0, 1], [0, 2]])
    np.testing.assert_array_equal(batch["prev_actions"][0].numpy(), [0, 1, 2])
    np.testing.assert_array_equal(batch["prev_rewards"][0].numpy(), [0, 0, 1])
    np.testing.assert_array_equal(batch["prev_dones"][0].numpy(), [False, False, True])
    # every position's label is the action taken from its own state: the next transition's action
    np.testing.assert_array_equal(batch["action_labels"][0].numpy(), [1, 2, 3])
    # window 1 starts a history: no previous step at position 0
    np.testing.assert_array_equal(batch["has_prev"][1].numpy(), [False, True, True])
    np.testing.assert_array_equal(batch["prev_states"][1, 0].numpy(), [0, 0])
    assert batch["prev_rewards"][1, 0] == 0 and not batch["prev_dones"][1, 0]
    np.testing.assert_array_equal(batch["action_labels"][1].numpy(), [0, 1, 2])
    assert batch["label_mask"].all()


def test_query_label_positions_label_only_the_last_position():
    batch = make_collator(toy_arrays(), toy_config(label_positions="query"))(
        [{"start": 2, "has_prev": True}]
    )
    np.testing.assert_array_equal(batch["label_mask"][0].numpy(), [False, False, True])


def test_dicp_collator_targets_by_hand():
    batch = make_collator(toy_arrays(), toy_config("dicp"))([{"start": 1, "has_prev": True}])
    np.testing.assert_array_equal(batch["actions"][0].numpy(), [1, 2, 3])
    np.testing.assert_array_equal(batch["reward_labels"][0].numpy(), [0, 1, 0])
    # the true final state at the episode end (row 2), not the next episode's start state
    np.testing.assert_array_equal(batch["next_state_labels"][0].numpy(), [[0, 2], [8, 8], [1, 1]])
    np.testing.assert_array_equal(batch["return_labels"][0].numpy(), [1, 1, 2])


def test_dpt_collator_needs_optimal_actions():
    arrays = toy_arrays()
    arrays.optimal_actions = None
    with pytest.raises(ValueError, match="optimal actions"):
        make_collator(arrays, toy_config("dpt"))


def test_load_arrays_matches_the_frames(small_darkroom):
    ds = small_darkroom
    arrays = load_arrays(ds, integer_states=True, discrete_actions=True)
    t = ds.frame_table()
    np.testing.assert_array_equal(
        arrays.states, np.stack(t.column(C.OBS).to_numpy(zero_copy_only=False))
    )
    np.testing.assert_array_equal(arrays.actions, t.column(C.ACTION).to_numpy())
    np.testing.assert_array_equal(arrays.rewards, t.column(C.REWARD).to_numpy())
    hist = ds.histories.to_pandas()
    np.testing.assert_array_equal(arrays.history_start, hist[C.FROM_INDEX])
    np.testing.assert_array_equal(arrays.history_lengths, 200)
    # every episode's first return-to-go is its return
    ep = ds.episodes.to_pandas()
    np.testing.assert_allclose(
        arrays.returns_to_go[ep[C.FROM_INDEX]], ep[C.EPISODE_RETURN], rtol=1e-6
    )


def test_dpt_labels_are_the_oracle_actions(small_darkroom):
    """Darkroom's oracle by hand: toward the goal (task = row * 9 + col), rows first, then columns."""
    ds = small_darkroom
    arrays = load_arrays(ds, integer_states=True, discrete_actions=True)
    task_of_row = ds.frame_table([C.TASK_ID]).column(C.TASK_ID).to_numpy()
    config = icrl_config(
        "tiny", objective="dpt", state_dim=2, state_bins=9, action_dim=5, context_length=40
    )
    windows = WindowDataset(arrays, 40)
    items = [windows[i] for i in np.random.default_rng(0).integers(0, len(windows), 16)]
    batch = make_collator(arrays, config)(items)
    rows = np.array([it["start"] for it in items])[:, None] + np.arange(40)  # (16, 40)
    goal = np.stack(np.divmod(task_of_row[rows], 9), axis=-1)  # (16, 40, 2)
    d = goal - batch["states"].numpy()
    expected = np.select(
        [d[..., 0] > 0, d[..., 0] < 0, d[..., 1] > 0, d[..., 1] < 0], [0, 1, 2, 3], default=4
    )
    np.testing.assert_array_equal(batch["action_labels"].numpy(), expected)


def test_band_attention_items_are_sequences_labelled_everywhere():
    """attention="band": items are sequences of ``length`` transitions, every position labelled."""
    collate = make_collator(toy_arrays(), toy_config("ad", attention="band"), length=5)  # K = 3
    batch = collate([{"start": 1, "has_prev": True}, {"start": 6, "has_prev": False}])
    assert batch["states"].shape == (2, 5, 2) and batch["label_mask"].all()
    np.testing.assert_array_equal(batch["action_labels"][0].numpy(), [1, 2, 3, 4, 0])
    np.testing.assert_array_equal(batch["has_prev"][1].numpy(), [False] + [True] * 4)


def test_band_sequences_are_drawn_like_windows():
    ds = WindowDataset(toy_arrays(), 5)  # two histories of 6: 2 sequences each
    assert len(ds) == 4
    assert [ds[i] for i in range(4)] == [
        {"start": 0, "has_prev": False},
        {"start": 1, "has_prev": True},
        {"start": 6, "has_prev": False},
        {"start": 7, "has_prev": True},
    ]
