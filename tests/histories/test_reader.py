"""Reading datasets: plain ``datasets.load_dataset``, ``load_histories``, cards, errors."""

import json
import shutil

import datasets
import numpy as np
import pytest
import yaml

from lhf_hf import constants as C
from lhf_hf.histories import DatasetFormatError, load_histories
from lhf_hf.utils.outputs import MARKER


def test_load_dataset_default_and_tables(small_darkroom):
    root = str(small_darkroom.root)
    frames = datasets.load_dataset(root, split="train")
    assert frames.num_rows == 6000 and frames[0][C.OBS] == [4, 4]
    assert frames.features[C.OBS].feature.dtype == "int64"
    episodes = datasets.load_dataset(root, "episodes", split="train")
    histories = datasets.load_dataset(root, "histories", split="train")
    assert episodes.num_rows == 300 and histories.num_rows == 30
    assert histories[0][C.RETURNS] == small_darkroom.histories[0][C.RETURNS]


def test_load_histories_object(small_darkroom):
    ds = load_histories(small_darkroom.root)
    assert ds.env_id == "darkroom" and ds.horizon == 20
    assert ds.tasks.to_pandas()[C.TASK_ID].tolist() == [3, 40, 62]
    assert ds.tasks.to_pandas()[C.TASK_INDEX].tolist() == [0, 1, 2]
    assert ds.tasks.to_pandas()[C.SPLIT].tolist() == ["train", "train", "test"]  # split seed 0
    assert json.loads(ds.tasks[1][C.TASK_PARAMS]) == {"goal": [4, 4]}
    assert ds.frames.num_rows == 6000
    th = ds.task_histories(40)
    assert th.rewards.shape == (10, 200) and th.learner.count("random") == 3
    with pytest.raises(KeyError, match="task 41"):
        ds.task_histories(41)


def test_card_and_plot(small_darkroom):
    text = (small_darkroom.root / "README.md").read_text()
    front = yaml.safe_load(text.split("---")[1])
    assert {"LeRobot", "lhf", "in-context-rl"} <= set(front["tags"])
    names = {c["config_name"]: c["data_files"] for c in front["configs"]}
    assert names == {
        "default": "data/*/*.parquet",
        "episodes": "meta/episodes/*/*.parquet",
        "histories": "meta/histories/*/*.parquet",
    }
    assert (
        "| `observation.state` | int64 | (2,) |" in text and "ppo 21, random 9" in text
    )  # 3 tasks x (7 PPO + 3 random)
    assert "n_steps" in text and "stable-baselines3" in text
    # snippets name the folder absolute, as the selection and model cards do
    root = small_darkroom.root.resolve()
    assert f'load_histories("{root}")' in text and f'root="{root}")' in text
    # the settings table: the algorithm and protocol that ran, not the others' defaults
    settings = text.split("| setting | value |")[1].split("Library versions")[0]
    assert "| ppo |" in settings and "| noisy_fraction | `0.3` |" in settings
    assert "| sac |" not in settings and "ppo_backend" not in settings  # SB3 PPO: no backends
    png = (small_darkroom.root / C.CURVE_PATH).read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_not_a_dataset(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_histories(tmp_path / "nope")
    with pytest.raises(DatasetFormatError, match=r"info.json is missing$"):
        load_histories(tmp_path)


def test_a_missing_info_json_is_told_apart_by_the_manifest(small_darkroom, tmp_path):
    """info.json is written last: missing from a finished dataset (its manifest lists it) it was
    removed; missing where the config exists and no manifest is finished, the collection never
    ended."""
    removed = tmp_path / "removed"
    shutil.copytree(small_darkroom.root, removed)
    (removed / C.INFO_PATH).unlink()
    with pytest.raises(DatasetFormatError, match="manifest of the finished dataset lists it"):
        load_histories(removed)
    (removed / MARKER).write_text(json.dumps({"kind": "dataset", "files": None}))
    with pytest.raises(DatasetFormatError, match="an unfinished collection: run it again"):
        load_histories(removed)


def test_malformed_datasets(small_darkroom, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(small_darkroom.root, bad)
    info = json.loads((bad / C.INFO_PATH).read_text())
    info["codebase_version"] = "v2.1"
    (bad / C.INFO_PATH).write_text(json.dumps(info))
    with pytest.raises(DatasetFormatError, match="v3.0"):
        load_histories(bad)
    info["codebase_version"] = "v3.0"
    del info["features"][C.REWARD]
    (bad / C.INFO_PATH).write_text(json.dumps(info))
    with pytest.raises(DatasetFormatError, match="next.reward"):
        load_histories(bad)
    shutil.copy(small_darkroom.root / C.INFO_PATH, bad / C.INFO_PATH)
    (bad / C.HISTORIES_PATH).unlink()
    with pytest.raises(DatasetFormatError, match="histories"):
        load_histories(bad)
    shutil.copytree(small_darkroom.root, tmp_path / "bad2")
    (tmp_path / "bad2" / "data/chunk-000/file-001.parquet").unlink()
    with pytest.raises(DatasetFormatError, match="data files are missing"):
        load_histories(tmp_path / "bad2").frame_table()


def test_derive_half(small_darkroom, tmp_path):
    from lhf_hf.histories.derive import derive_half

    half = derive_half(small_darkroom.root, tmp_path / "half", progress=False)
    assert half.lhf["steps_per_history"] == 100 and half.info["total_frames"] == 3000
    d = half.lhf["derived_from"]
    assert d["op"] == "half" and d["source_fingerprint"] == small_darkroom.fingerprint
    assert d["source_collect"]["protocol"] == "noisy"
    src = small_darkroom.task_histories(40)
    new = half.task_histories(40)
    np.testing.assert_array_equal(new.obs, src.obs[:, :100])
    np.testing.assert_array_equal(new.rewards, src.rewards[:, :100])
    assert new.learner == src.learner
    returns = half.histories.to_pandas()[C.RETURNS]
    assert all(len(r) == 5 for r in returns)
    np.testing.assert_allclose(returns[0], small_darkroom.histories[0][C.RETURNS][:5])
    assert "Derived dataset" in (half.root / "README.md").read_text()
    with pytest.raises(ValueError, match="less than one episode"):
        derive_half(small_darkroom.root, tmp_path / "tiny", fraction=0.01, progress=False)


def test_derive_refuses_a_source_that_fails_verify(small_darkroom, tmp_path):
    """Zeroed actions in a data file keep its rows and columns (so it loads), but no longer hash
    to the fingerprint: nothing is derived from it."""
    import shutil

    import pyarrow as pa
    import pyarrow.parquet as pq

    from lhf_hf.histories.derive import derive_half

    src = tmp_path / "src"
    shutil.copytree(small_darkroom.root, src)
    f = src / "data/chunk-000/file-000.parquet"
    t = pq.read_table(f)
    i = t.schema.get_field_index(C.ACTION)
    pq.write_table(t.set_column(i, C.ACTION, pa.array([0] * t.num_rows, t.schema.field(i).type)), f)
    with pytest.raises(ValueError, match="fails `lhf verify` .*fingerprint.*nothing derived"):
        derive_half(src, tmp_path / "half", progress=False)
    assert not (tmp_path / "half").exists()


def test_episode_stats_are_numpys_over_each_episodes_frames(small_darkroom):
    """LeRobot v3.0's per-episode ``stats/*`` columns, against numpy on the frames themselves."""
    episodes = small_darkroom.episodes.data.table
    frames = small_darkroom.frame_table([C.OBS, C.REWARD, C.EPISODE_INDEX])
    obs = np.array(frames.column(C.OBS).to_pylist(), dtype=float).reshape(-1, 20, 2)
    reward = frames.column(C.REWARD).to_numpy().astype(float).reshape(-1, 20)
    assert episodes.column(C.EPISODE_INDEX).to_pylist() == list(range(len(obs)))
    for stat, fn in (("min", np.min), ("max", np.max), ("mean", np.mean), ("std", np.std)):
        got = np.array(episodes.column(f"stats/{C.OBS}/{stat}").to_pylist())
        np.testing.assert_allclose(got, fn(obs, axis=1), atol=1e-12)
        got = np.array(episodes.column(f"stats/{C.REWARD}/{stat}").to_pylist())[:, 0]
        np.testing.assert_allclose(got, fn(reward, axis=1), atol=1e-6)
    assert set(episodes.column(f"stats/{C.REWARD}/count").to_pylist()[0]) == {20}
    ret = episodes.column(C.EPISODE_RETURN).to_numpy()
    np.testing.assert_allclose(ret, reward.sum(1), rtol=1e-5)
    assert episodes.column(C.EPISODE_TASKS).to_pylist()[0] == [small_darkroom.tasks["task"][0]]


def test_card_from_its_metadata_alone(learned_darkroom, tmp_path):
    """``dataset_cards/`` renders cards from the metadata files alone: the same text."""
    import shutil as sh

    from lhf_hf.histories.card import CARD_SOURCES, CardInputs, render_card, render_card_of

    for rel in CARD_SOURCES:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        sh.copy(learned_darkroom.root / rel, tmp_path / rel)
    alone = render_card_of(CardInputs.read(tmp_path), "org/name")
    assert alone == render_card(learned_darkroom, "org/name")
    assert 'load_dataset("org/name", split="train", revision="v3.0")' in alone
    assert str(tmp_path) not in alone
    settings = alone.split("| setting | value |")[1].split("Library versions")[0]
    assert "| ppo_backend |" in settings and "noisy_fraction" not in settings
    with pytest.raises(ValueError, match="needs a load_path"):
        render_card_of(CardInputs.read(tmp_path))
