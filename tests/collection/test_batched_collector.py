"""The batched collector: determinism, chunks, resume, protocols, errors."""

import numpy as np
import pytest

from lhf_hf import constants as C
from lhf_hf.collection import collect
from lhf_hf.configs import CollectConfig

CFG = dict(
    env_id="darkroom", tasks="5,6,7", histories=6, steps=100, collector="batched", tasks_per_chunk=2
)


@pytest.mark.slow
def test_same_seed_same_data_and_chunks_matter(tmp_path):
    # 3 writer threads vs writing in this thread: the same files
    a = collect(CollectConfig(**CFG, workers=3), tmp_path / "a", progress=False)
    b = collect(CollectConfig(**CFG, workers=1), tmp_path / "b", progress=False)
    assert a.fingerprint == b.fingerprint and a.frame_table().equals(b.frame_table())
    assert a.lhf["collect"]["tasks_per_chunk"] == 2 and a.lhf["collect"]["collector"] == "batched"
    c = collect(CollectConfig(**{**CFG, "tasks_per_chunk": 3}), tmp_path / "c", progress=False)
    assert c.fingerprint != a.fingerprint  # documented: a chunk's random stream depends on its size


@pytest.mark.slow
def test_resume_redoes_whole_chunks_identically(tmp_path, capsys):
    # --resume with nothing to resume starts the collection, and says so
    full = collect(CollectConfig(**CFG), tmp_path / "full", resume=True, progress=False)
    assert (
        f"--resume: {tmp_path / 'full'} held no collection; starting one" in capsys.readouterr().err
    )
    out = tmp_path / "partial"
    from lhf_hf.collection.batched_collector import collect_chunk, resolve_ppo_backend
    from lhf_hf.histories.writer import claim_dataset, write_task

    cfg = CollectConfig(**CFG)
    cfg.ppo_backend = resolve_ppo_backend(cfg)  # as collect() does before writing
    with claim_dataset(out, cfg.identity()):
        # chunk 0 (positions 0, 1) fully committed, chunk 1 (position 2) missing: as after a kill
        for p, th in zip([0, 1], collect_chunk(cfg, [5, 6], 0), strict=True):
            write_task(out, p, th, cfg.horizon)
    capsys.readouterr()
    resumed = collect(cfg, out, resume=True, progress=False)
    assert resumed.fingerprint == full.fingerprint
    # said: the chunk of positions 0-1 is committed, position 2 is redone
    err = capsys.readouterr().err
    assert "resuming, 2 of 3 task(s) already committed" in err and "held no collection" not in err


@pytest.mark.slow
def test_background_writer_error_surfaces_and_resume_completes(tmp_path, monkeypatch):
    """Chunks are written in the background while the next one collects: a failed write is raised
    (not swallowed), the tasks already committed stay, and --resume completes the same dataset."""
    import importlib

    from lhf_hf.histories.writer import task_done, write_task

    collect_mod = importlib.import_module("lhf_hf.collection.driver")

    full = collect(CollectConfig(**CFG), tmp_path / "full", progress=False)
    cfg = CollectConfig(**CFG)

    def failing(out, position, th, horizon):
        if position == 1:
            raise OSError("disk full")
        write_task(out, position, th, horizon)

    monkeypatch.setattr(collect_mod, "write_task", failing)
    out = tmp_path / "partial"
    with pytest.raises(OSError, match="disk full"):
        collect(cfg, out, progress=False)
    assert task_done(out, 0, cfg.frames_per_task) and not task_done(out, 1, cfg.frames_per_task)
    monkeypatch.setattr(collect_mod, "write_task", write_task)
    assert collect(cfg, out, resume=True, progress=False).fingerprint == full.fingerprint


def test_independent_protocol_has_one_learner_per_history(tmp_path):
    ds = collect(
        CollectConfig(**{**CFG, "tasks": "5", "protocol": "independent"}),
        tmp_path / "i",
        progress=False,
    )
    hist = ds.histories.to_pandas()
    assert hist[C.LEARNER_INDEX].tolist() == list(range(6))
    th = ds.task_histories(5)
    assert not np.array_equal(th.actions[0], th.actions[1])


def test_learners_protocol_has_learners_over_several_copies_each(tmp_path):
    """K learners per task, each over H / K copies: the histories table names each history's
    learner, and a learner's copies and the learners all act differently."""
    cfg = CollectConfig(**{**CFG, "tasks": "5", "protocol": "learners", "learners": 3})
    assert cfg.identity()["learners"] == 3 and "learners" not in CollectConfig(**CFG).identity()
    ds = collect(cfg, tmp_path / "k", progress=False)
    hist = ds.histories.to_pandas()
    assert hist[C.LEARNER_INDEX].tolist() == [0, 0, 1, 1, 2, 2]
    th = ds.task_histories(5)
    assert not np.array_equal(th.actions[0], th.actions[1])  # two copies of learner 0
    assert not np.array_equal(th.actions[0], th.actions[2])  # learners 0 and 1


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(protocol="learners", learners=4), "learners must divide histories"),
        (dict(protocol="learners", learners=0), "learners must divide histories"),
        (dict(env_id="metaworld-reach", steps=100), "gridworlds only"),
        (dict(tasks_per_chunk=0), "tasks_per_chunk"),
    ],
)
def test_config_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        CollectConfig(**{**CFG, "tasks": "0", **kwargs})


def test_default_chunk_bounds_memory():
    cfg = CollectConfig("dark-key-to-door", histories=100, steps=1000, collector="batched")
    assert cfg.tasks_per_chunk == 500  # 50M transitions per chunk


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["torch", "kernel"])
def test_the_thread_count_does_not_change_the_data(tmp_path, backend):
    # LAPACK's QR (the orthogonal initialisation) rounded differently at 1 and 2 threads, and PPO
    # turned that last bit into other histories: the data depended on the machine's core count.
    import torch

    if backend == "kernel":
        from lhf_hf.collection import native

        try:
            native.load(64)
        except native.KernelUnavailable as e:
            pytest.skip(f"no C++ kernel here: {e}")
    cfg = {**CFG, "tasks": "0,1,2,3", "histories": 20, "steps": 500, "ppo_backend": backend}
    old = torch.get_num_threads()
    found = []
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            out = collect(CollectConfig(**cfg, workers=1), tmp_path / f"t{threads}", progress=False)
            found.append(out.fingerprint)
            assert torch.get_num_threads() == threads  # the initialisation restores it
    finally:
        torch.set_num_threads(old)
    assert found[0] == found[1]
