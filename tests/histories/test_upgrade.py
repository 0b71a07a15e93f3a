"""``lhf upgrade``: a dataset written by lhf's layout 1 (``fixtures/layout1_darkroom``, made by
lhf_hf at commit 31a2e08: env tasks 5, 17, 64 in the frames' ``task_index``) becomes the current
layout with the same transitions."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from lhf_hf import constants as C
from lhf_hf.cli.main import main
from lhf_hf.configs import TrainConfig
from lhf_hf.histories import load_histories
from lhf_hf.histories import upgrade as upgrade_module
from lhf_hf.histories.reader import DatasetFormatError
from lhf_hf.histories.upgrade import upgrade
from lhf_hf.training import train
from lhf_hf.training.trainer import IDENTITY_FILE
from lhf_hf.verify import verify

FIXTURE = Path(__file__).with_name("fixtures") / "layout1_darkroom"
OLD_TASKS = [5, 17, 64]


@pytest.fixture
def old(tmp_path) -> Path:
    root = tmp_path / "old"
    shutil.copytree(FIXTURE, root)
    return root


def _old_frames(root: Path):
    return [pq.read_table(root / C.DATA_PATH.format(chunk_index=0, file_index=p)) for p in range(3)]


def test_reader_names_the_upgrade(old):
    with pytest.raises(DatasetFormatError, match=f"run `lhf upgrade {old}` once"):
        load_histories(old)


@pytest.mark.slow
def test_upgrade_keeps_every_transition_and_makes_task_index_dense(old, capsys):
    before = _old_frames(old)
    old_info = json.loads((old / C.INFO_PATH).read_text())["lhf"]
    old_hist = pq.read_table(old / C.HISTORIES_PATH)
    assert main(["upgrade", str(old)]) == 0
    assert "upgraded to lhf layout 2" in capsys.readouterr().out
    ds = load_histories(old)
    assert ds.lhf["tasks"] == OLD_TASKS and ds.lhf["layout_version"] == C.LAYOUT_VERSION
    assert ds.lhf["upgraded"]["fingerprint"] == old_info["fingerprint"] != ds.fingerprint
    assert ds.lhf["created"] == old_info["created"] and ds.lhf["collect"] == old_info["collect"]
    assert "lhf" not in ds.info
    for p, (task, was) in enumerate(zip(OLD_TASKS, before, strict=True)):
        now = ds.task_frames(task)
        assert now.column(C.TASK_ID).to_pylist() == was.column(C.TASK_INDEX).to_pylist()
        assert set(now.column(C.TASK_INDEX).to_pylist()) == {p}
        for col in (C.OBS, C.ACTION, C.REWARD, C.NEXT_OBS, C.DONE, C.INDEX, C.EPISODE_INDEX):
            assert now.column(col).equals(was.column(col)), col
    hist = ds.histories.data.table
    assert hist.column(C.RETURNS).equals(old_hist.column(C.RETURNS))
    assert hist.column(C.TASK_ID).equals(old_hist.column(C.TASK_INDEX))
    tasks = ds.tasks.to_pandas()
    assert tasks[C.TASK_INDEX].tolist() == [0, 1, 2] and tasks[C.TASK_ID].tolist() == OLD_TASKS
    assert verify(old)["problems"] == []
    # a second upgrade has nothing to do, and says so
    assert main(["upgrade", str(old)]) == 0
    assert "already in lhf's layout 2: nothing to do" in capsys.readouterr().out


def test_an_interrupted_upgrade_is_finished_by_running_it_again(old, monkeypatch, tmp_path):
    reference = tmp_path / "reference"
    shutil.copytree(FIXTURE, reference)
    upgrade(reference, echo=lambda _: None)
    real = upgrade_module.write_task
    calls = []

    def write_then_stop(root, position, th, horizon):
        calls.append(position)
        if position == 1:
            raise KeyboardInterrupt
        real(root, position, th, horizon)

    monkeypatch.setattr(upgrade_module, "write_task", write_then_stop)
    with pytest.raises(KeyboardInterrupt):
        upgrade(old, echo=lambda _: None)
    assert calls == [0, 1]  # data file 0 is in the new layout, 1 and 2 in the old
    with pytest.raises(DatasetFormatError, match="lhf upgrade"):
        load_histories(old)
    monkeypatch.setattr(upgrade_module, "write_task", real)
    upgrade(old, echo=lambda _: None)
    done, ref = load_histories(old), load_histories(reference)
    assert done.fingerprint == ref.fingerprint and done.frame_table().equals(ref.frame_table())


def test_upgrade_refuses_what_is_not_an_lhf_dataset(tmp_path):
    with pytest.raises(Exception, match="is not a learning-history dataset"):
        upgrade(tmp_path)
    (tmp_path / "meta").mkdir()
    (tmp_path / C.INFO_PATH).write_text(json.dumps({"codebase_version": "v3.0"}))
    with pytest.raises(Exception, match="has no lhf section"):
        upgrade(tmp_path)


@pytest.mark.slow
def test_a_training_resumes_on_its_upgraded_data(old, tmp_path):
    """A run interrupted on layout-1 data resumes on the upgraded copy (the same histories under
    a new fingerprint); a checkpoint of other data is still refused."""
    before = json.loads((old / C.INFO_PATH).read_text())["lhf"]["fingerprint"]
    assert main(["upgrade", str(old)]) == 0
    cfg = dict(
        dataset=str(old),
        objective="ad",
        preset="tiny",
        batch_size=4,
        context_length=20,
        max_steps=4,
        save_steps=2,
        logging_steps=10,
    )
    full = train(TrainConfig(out=str(tmp_path / "full"), **cfg))
    part = tmp_path / "part"
    part.mkdir()
    shutil.copytree(full / "checkpoint-2", part / "checkpoint-2")
    # what the previous release wrote: the identity names the layout-1 fingerprint
    identity_path = part / "checkpoint-2" / IDENTITY_FILE
    identity = json.loads(identity_path.read_text())
    identity.pop("dataset_upgraded_from")
    identity_path.write_text(json.dumps(identity | {"dataset_fingerprint": before}))
    resumed = train(TrainConfig(out=str(part), resume=True, **cfg))
    assert (resumed / "model.safetensors").read_bytes() == (full / "model.safetensors").read_bytes()
    shutil.rmtree(part / "checkpoint-4")
    identity_path.write_text(json.dumps(identity | {"dataset_fingerprint": "0" * 64}))
    with pytest.raises(ValueError, match="different setup \\(dataset: 0000000000000000 -> "):
        train(TrainConfig(out=str(part), resume=True, **cfg))
