"""ppo_backend="auto" picks the backend measured faster on this machine, once, and says so."""

from __future__ import annotations

import json

import pytest

from lhf_hf.collection import backend_verdict, native
from lhf_hf.collection.batched_collector import resolve_ppo_backend
from lhf_hf.configs import CollectConfig

KW = dict(env_id="darkroom", tasks="0", histories=2, steps=100, collector="batched")


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("LHF_HF_KERNEL_CACHE", str(tmp_path))
    native.build.cache_clear()
    native.load.cache_clear()
    yield tmp_path
    native.build.cache_clear()
    native.load.cache_clear()


@pytest.mark.slow
def test_the_verdict_is_measured_once_cached_and_honoured(cache, monkeypatch):
    v = backend_verdict.verdict(2, 5)
    assert not v["cached"] and v["kernel_ms"] > 0 and v["torch_ms"] > 0
    assert v["choice"] == ("kernel" if v["kernel_ms"] <= v["torch_ms"] else "torch")
    assert v["isa"] in ("avx512", "avx2", "other") and v["cpu"]
    (path,) = cache.glob("verdict-*.json")

    def no_measuring(*args):
        raise AssertionError("a cached verdict is not measured again")

    monkeypatch.setattr(backend_verdict, "measure", no_measuring)
    assert backend_verdict.verdict(2, 5)["cached"]
    # the cached verdict decides, whichever it says
    for choice in ("torch", "kernel"):
        path.write_text(json.dumps({**json.loads(path.read_text()), "choice": choice}))
        assert resolve_ppo_backend(CollectConfig(**KW)) == choice
    # explicit choices are never overridden by the verdict
    assert resolve_ppo_backend(CollectConfig(**KW, ppo_backend="kernel")) == "kernel"
    path.write_text(json.dumps({**json.loads(path.read_text()), "choice": "kernel"}))
    assert resolve_ppo_backend(CollectConfig(**KW, ppo_backend="torch")) == "torch"
    # another CPU (another -march=native) is another verdict file
    monkeypatch.setattr(native, "_native_target", lambda cxx, march="native": "-march=znver3")
    native.build.cache_clear()
    monkeypatch.setattr(backend_verdict, "measure", lambda *a: {"kernel_ms": 2.0, "torch_ms": 1.0})
    assert backend_verdict.verdict(2, 5)["choice"] == "torch"
    assert len(list(cache.glob("verdict-*.json"))) == 2


@pytest.mark.slow
def test_one_verdict_whatever_the_thread_count_of_the_process(cache, monkeypatch):
    # lhf reproduce --jobs 2 resolves auto in its own process (two threads) and in each stage's
    # child (one): both must name the same backend, or a child does not find its stage's hash
    import torch

    seen = []
    real = backend_verdict._measure

    def spy(*args):
        seen.append(torch.get_num_threads())
        return real(*args)

    monkeypatch.setattr(backend_verdict, "_measure", spy)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        first = backend_verdict.verdict(2, 5)
        assert torch.get_num_threads() == 2  # put back after measuring
        torch.set_num_threads(1)
        again = backend_verdict.verdict(2, 5)
    finally:
        torch.set_num_threads(before)
    assert seen == [1] and not first["cached"] and again["cached"]
    assert again["path"] == first["path"] and again["choice"] == first["choice"]
    assert first["threads"] == 1


@pytest.mark.slow
def test_the_collection_records_where_it_ran(cache, tmp_path):
    from lhf_hf.collection import collect

    ds = collect(CollectConfig(**KW, workers=1), tmp_path / "d", progress=False)
    m = ds.lhf["machine"]
    assert m["ppo_backend"] == ds.lhf["collect"].get("ppo_backend", "torch")
    assert m["ppo_verdict"]["choice"] == m["ppo_backend"]
    assert m["cpu"] and m["isa"] in ("avx512", "avx2", "other")
    # the kernel's -march (native unless $LHF_HF_KERNEL_MARCH says) where the kernel ran
    if m["ppo_backend"] == "kernel":
        assert m["kernel_march"] == native.target_march()
    else:
        assert "kernel_march" not in m
    assert "machine" not in ds.lhf["collect"]  # not part of the data's identity
    torch_ds = collect(
        CollectConfig(**KW, workers=1, ppo_backend="torch"), tmp_path / "t", progress=False
    )
    assert "kernel_march" not in torch_ds.lhf["machine"]  # no kernel ran
    kernel_ds = collect(
        CollectConfig(**KW, workers=1, ppo_backend="kernel"), tmp_path / "k", progress=False
    )
    assert kernel_ds.lhf["machine"]["kernel_march"] == "native"
