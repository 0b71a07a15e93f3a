"""Invariants of real collected data (issue: collection; docs/design.md sections 3-4)."""

import numpy as np
import pyarrow.parquet as pq

from lhf_hf import constants as C
from lhf_hf.envs.gridworld_core import MOVES


def frames(ds):
    t = ds.frame_table()
    obs = np.stack(t.column(C.OBS).to_numpy(zero_copy_only=False))
    nxt = np.stack(t.column(C.NEXT_OBS).to_numpy(zero_copy_only=False))
    return t, obs, nxt


def test_episode_return_is_sum_of_rewards(collected):
    t, _, _ = frames(collected)
    rewards = t.column(C.REWARD).to_numpy()
    episode = t.column(C.EPISODE_INDEX).to_numpy()
    sums = np.bincount(episode, weights=rewards)
    ep = collected.episodes.to_pandas().sort_values(C.EPISODE_INDEX)
    np.testing.assert_allclose(ep[C.EPISODE_RETURN].to_numpy(), sums, rtol=0, atol=1e-6)
    # and the histories table lists the same returns, in episode order
    hist = collected.histories.to_pandas()
    for _, row in hist.iterrows():
        mine = ep[ep[C.HISTORY_INDEX] == row[C.HISTORY_INDEX]].sort_values(C.EPISODE_IN_HISTORY)
        np.testing.assert_allclose(row[C.RETURNS], mine[C.EPISODE_RETURN].to_numpy())


def test_next_state_chains_within_episodes_and_is_true_at_the_end(collected):
    t, obs, nxt = frames(collected)
    done = t.column(C.DONE).to_numpy()
    history = t.column(C.HISTORY_INDEX).to_numpy()
    same_history = history[:-1] == history[1:]
    inner = ~done[:-1] & same_history
    np.testing.assert_array_equal(nxt[:-1][inner], obs[1:][inner])
    # every transition, episode ends included, follows the dynamics from the logged state and action:
    # the final next state is a real successor, not the reset state (4, 4)
    action = t.column(C.ACTION).to_numpy()
    expected = np.clip(obs + MOVES[action], 0, 8)
    np.testing.assert_array_equal(nxt, expected)
    ends = np.flatnonzero(done)
    assert np.any(~np.all(nxt[ends] == [4, 4], axis=1)), (
        "final states should not all be the reset state"
    )
    # an episode starts at the centre
    first = t.column(C.FRAME_INDEX).to_numpy() == 0
    assert np.all(obs[first] == [4, 4])


def test_reward_and_oracle_follow_the_task(collected):
    t, obs, nxt = frames(collected)
    task = t.column(C.TASK_ID).to_numpy()
    goal = np.stack(np.divmod(task, 9), axis=1)
    np.testing.assert_array_equal(
        t.column(C.REWARD).to_numpy(), np.all(nxt == goal, axis=1).astype(np.float32)
    )
    opt = t.column(C.OPTIMAL_ACTION).to_numpy()
    # rows first, then columns, then stay
    d = goal - obs
    expected = np.where(
        d[:, 0] > 0,
        0,
        np.where(d[:, 0] < 0, 1, np.where(d[:, 1] > 0, 2, np.where(d[:, 1] < 0, 3, 4))),
    )
    np.testing.assert_array_equal(opt, expected)


def test_histories_are_contiguous_slices_with_whole_episodes(collected):
    ds = collected
    t = ds.frame_table([C.INDEX, C.HISTORY_INDEX, C.EPISODE_INDEX, C.FRAME_INDEX])
    index = t.column(C.INDEX).to_numpy()
    np.testing.assert_array_equal(index, np.arange(len(index)))
    history = t.column(C.HISTORY_INDEX).to_numpy()
    hist = ds.histories.to_pandas()
    assert len(hist) == 3 * 10
    for _, row in hist.iterrows():
        rows = np.flatnonzero(history == row[C.HISTORY_INDEX])
        assert rows[0] == row[C.FROM_INDEX] and rows[-1] + 1 == row[C.TO_INDEX]
        assert len(rows) == 200 and np.all(np.diff(rows) == 1)
        assert row[C.NUM_EPISODES] == len(row[C.RETURNS]) == 200 // 20
    ep = ds.episodes.to_pandas()
    assert (ep[C.LENGTH] == 20).all() and len(ep) == 30 * 10
    assert (ep[C.TO_INDEX] - ep[C.FROM_INDEX] == 20).all()
    frame_index = t.column(C.FRAME_INDEX).to_numpy()
    np.testing.assert_array_equal(frame_index, np.tile(np.arange(20), len(index) // 20))


def test_noisy_protocol_has_exactly_30_percent_random(collected):
    hist = collected.histories.to_pandas()
    for _, group in hist.groupby(C.TASK_ID):
        assert (group[C.LEARNER] == "random").sum() == 3 and (group[C.LEARNER] == "ppo").sum() == 7
        assert (
            group[group[C.LEARNER] == "ppo"][C.SEED].nunique() == 1
        )  # paper protocol: one learner
    # random histories are uniformly random: all 5 actions, each ~20% of the time
    t = collected.frame_table([C.ACTION, C.HISTORY_INDEX])
    random_ids = hist.loc[hist[C.LEARNER] == "random", C.HISTORY_INDEX].to_numpy()
    acts = t.column(C.ACTION).to_numpy()[np.isin(t.column(C.HISTORY_INDEX).to_numpy(), random_ids)]
    freq = np.bincount(acts, minlength=5) / len(acts)
    assert np.all(np.abs(freq - 0.2) < 0.04)


def test_info_records_config_versions_seeds(collected):
    lhf = collected.lhf
    assert lhf["collect"]["protocol"] == "noisy" and lhf["collect"]["tasks"] == [3, 40, 62]
    assert lhf["collect"]["ppo"] == {
        "n_steps": 20,
        "batch_size": 50,
        "n_epochs": 20,
        "learning_rate": 3e-4,
        "gamma": 0.99,
    }
    for lib in ("stable-baselines3", "torch", "gymnasium", "datasets", "lhf_hf"):
        assert lib in lhf["versions"]
    assert lhf["seed"] == 0 and len(lhf["fingerprint"]) == 64
    info = collected.info
    assert (
        info["codebase_version"] == "v3.0"
        and info["total_frames"] == 6000
        and info["total_episodes"] == 300
    )
    assert info["features"][C.OBS] == {"dtype": "int64", "shape": [2], "names": ["row", "col"]}
    assert info["features"][C.ACTION]["dtype"] == "int64"


def test_stats_match_the_frames(collected):
    t, obs, _ = frames(collected)
    s = collected.stats[C.OBS]
    np.testing.assert_allclose(s["mean"], obs.mean(0))
    np.testing.assert_allclose(s["std"], obs.std(0), rtol=1e-6)
    assert s["min"] == obs.min(0).tolist() and s["count"] == [len(obs)]
    r = t.column(C.REWARD).to_numpy()
    np.testing.assert_allclose(collected.stats[C.REWARD]["mean"], [r.mean()], rtol=1e-6)


def test_parquet_files_in_lerobot_layout(collected):
    root = collected.root
    for p in range(3):
        f = root / f"data/chunk-000/file-{p:03d}.parquet"
        assert pq.ParquetFile(f).metadata.num_rows == 2000
    assert not (root / C.PARTS_DIR).exists()
