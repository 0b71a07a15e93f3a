"""Writer: atomic per-task commits, corruption detection, output-folder rules."""

import json

import numpy as np
import pytest

from lhf_hf import constants as C
from lhf_hf.histories.schema import TaskHistories
from lhf_hf.histories.writer import (
    OutputExistsError,
    claim_dataset,
    data_path,
    task_done,
    write_task,
)


def fake_task(task=5, H=3, T=40, horizon=20):
    rng = np.random.default_rng(task)
    obs = rng.integers(0, 9, (H, T, 2))
    dones = np.zeros((H, T), dtype=bool)
    dones[:, horizon - 1 :: horizon] = True
    return TaskHistories(
        task=task,
        obs=obs,
        actions=rng.integers(0, 5, (H, T)),
        rewards=rng.integers(0, 2, (H, T)).astype(np.float32),
        next_obs=obs.copy(),
        dones=dones,
        optimal_actions=rng.integers(0, 5, (H, T)),
        success=None,
        learner=["ppo"] * H,
        learner_index=np.zeros(H, dtype=np.int64),
        seeds=np.full(H, 7),
    )


def test_global_indices_depend_on_position_only(tmp_path):
    write_task(tmp_path, 2, fake_task(), horizon=20)
    import pyarrow.parquet as pq

    t = pq.read_table(tmp_path / data_path(2))
    assert t.column(C.INDEX).to_pylist()[0] == 2 * 3 * 40 and t.num_rows == 120
    assert t.column(C.HISTORY_INDEX).to_pylist()[::40] == [6, 7, 8]
    assert t.column(C.EPISODE_INDEX).to_pylist()[::20] == [12, 13, 14, 15, 16, 17]
    assert data_path(1234) == "data/chunk-001/file-234.parquet"


def test_task_done_detects_corruption(tmp_path):
    write_task(tmp_path, 0, fake_task(), horizon=20)
    assert task_done(tmp_path, 0, 120)
    assert not task_done(tmp_path, 0, 121)  # another config's size
    f = tmp_path / data_path(0)
    raw = bytearray(f.read_bytes())
    raw[len(raw) // 2] ^= 0xFF  # flip one byte: still readable metadata, wrong checksum
    f.write_bytes(bytes(raw))
    assert not task_done(tmp_path, 0, 120)
    write_task(tmp_path, 0, fake_task(), horizon=20)
    f.write_bytes(f.read_bytes()[:100])  # truncated
    assert not task_done(tmp_path, 0, 120)
    write_task(tmp_path, 0, fake_task(), horizon=20)
    (tmp_path / C.PARTS_DIR / "task-000000.json").unlink()  # killed before the marker
    assert not task_done(tmp_path, 0, 120)


def test_no_temporary_files_left(tmp_path):
    write_task(tmp_path, 0, fake_task(), horizon=20)
    assert not list(tmp_path.rglob("*.tmp"))


def test_invalid_histories_rejected(tmp_path):
    th = fake_task()
    th.rewards[0, 3] = np.nan
    with pytest.raises(ValueError, match="non-finite rewards"):
        write_task(tmp_path, 0, th, horizon=20)
    th = fake_task()
    th.dones[0, 5] = True
    with pytest.raises(ValueError, match="every 20 steps"):
        write_task(tmp_path, 0, th, horizon=20)
    th = fake_task()
    with pytest.raises(ValueError, match="multiple of the horizon"):
        write_task(tmp_path, 0, th, horizon=30)
    th = fake_task(H=3, T=40)
    th.rewards = th.rewards[:, :0]
    with pytest.raises(ValueError, match="empty"):
        write_task(tmp_path, 0, th, horizon=20)
    assert not (tmp_path / data_path(0)).exists()


def test_claim_dataset_rules(tmp_path):
    ident = {"env_id": "darkroom", "seed": 0}
    out = tmp_path / "out"
    with claim_dataset(out, ident):
        pass
    assert json.loads((out / C.CONFIG_PATH).read_text()) == ident
    with pytest.raises(OutputExistsError, match="--resume"):
        with claim_dataset(out, ident):
            pass
    with claim_dataset(out, ident, resume=True):
        pass
    with pytest.raises(OutputExistsError, match=r"different config \(seed: 0 -> 1\)"):
        with claim_dataset(out, {**ident, "seed": 1}, resume=True):
            pass
    with claim_dataset(out, {**ident, "seed": 1}, overwrite=True):
        pass
    assert json.loads((out / C.CONFIG_PATH).read_text())["seed"] == 1
    stranger = tmp_path / "mine"
    stranger.mkdir()
    (stranger / "thesis.tex").write_text("precious")
    for kw in ({"overwrite": True}, {"resume": True}):
        with pytest.raises(OutputExistsError, match="not an lhf dataset"):
            with claim_dataset(stranger, ident, **kw):
                pass
    assert (stranger / "thesis.tex").read_text() == "precious"
