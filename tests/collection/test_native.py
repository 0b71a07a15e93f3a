"""The C++ PPO kernel: its build, its tanh, and its update against the torch implementation."""

import ctypes
import logging
import stat

import numpy as np
import pytest
import torch

from lhf_hf.collection import native
from lhf_hf.collection.batched_ppo import StackedPolicy, make_optimizer
from lhf_hf.collection.ppo_backends import ppo_update
from lhf_hf.utils import native_build

from .rollouts import random_rollout


def kernel_tanh(x: torch.Tensor) -> torch.Tensor:
    lib = native.load(64)
    x = x.contiguous()
    y = torch.empty_like(x)
    lib.lhf_tanh(
        ctypes.c_void_p(x.data_ptr()), ctypes.c_void_p(y.data_ptr()), ctypes.c_int64(x.numel())
    )
    return y


@pytest.mark.slow
def test_build_is_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("LHF_HF_KERNEL_CACHE", str(tmp_path))
    native.build.cache_clear()
    try:
        path = native.build(64)
        assert path.parent == tmp_path and path.exists()
        mtime = path.stat().st_mtime_ns
        native.build.cache_clear()
        assert native.build(64) == path and path.stat().st_mtime_ns == mtime  # not rebuilt
        assert not list(tmp_path.glob("*.tmp"))  # written under a temporary name, then renamed
    finally:
        native.build.cache_clear()


@pytest.mark.slow
def test_the_kernel_cache_loads_only_what_it_built(tmp_path, monkeypatch):
    """A foreign, corrupt or truncated library under the cached name is rebuilt, never loaded;
    the cache must be private; the key covers what -march=native means on this CPU."""
    cache = tmp_path / "kernels"
    monkeypatch.setenv("LHF_HF_KERNEL_CACHE", str(cache))
    native.build.cache_clear()
    try:
        path = native.build(64)
        assert stat.S_IMODE(cache.stat().st_mode) == 0o700
        good = path.read_bytes()
        for bad in (b"\x7fELF not a library", good[: len(good) // 2]):  # foreign, truncated
            path.write_bytes(bad)
            native.build.cache_clear()
            assert native.build(64) == path and path.read_bytes() != bad
            assert native_build.verified(path)
        path.with_name(path.name + ".sha256").unlink()  # no record: not trusted either
        native.build.cache_clear()
        native.build(64)
        assert native_build.verified(path)
        # another CPU (another expansion of -march=native) is another library
        monkeypatch.setattr(
            native, "_native_target", lambda cxx, march="native": "-march=znver3 -mno-avx512f"
        )
        native.build.cache_clear()
        other = native.build(64)
        assert other != path and native_build.verified(other)
        cache.chmod(0o777)  # anyone could plant a library: refused, with the fix in the message
        native.build.cache_clear()
        with pytest.raises(native.KernelUnavailable, match="is not private .*chmod 700"):
            native.build(64)
    finally:
        cache.chmod(0o700)
        native.build.cache_clear()


def test_tanh_matches_float64_tanh():
    x = torch.cat(
        [
            torch.linspace(-20, 20, 200_001),
            torch.logspace(-8, 1, 10_001),
            -torch.logspace(-8, 1, 10_001),
            torch.tensor([0.0, -0.0, 0.625, -0.625, 9.0, 1e30, -1e30]),
        ]
    )  # odd length: the scalar tail too
    y = kernel_tanh(x).double()
    ref = torch.tanh(x.double())
    abs_err = (y - ref).abs()
    # the rational fit's float evaluation: <= 3.6e-7 relative over every float (a few ulps; measured
    # over all 2.8e8 floats in [2^-30, 10] when the coefficients were fitted, scripts/fit_tanh.py)
    assert float(abs_err.max()) < 4e-7
    rel = abs_err / ref.abs().clamp_min(1e-30)
    assert float(rel[ref.abs() > 0].max()) < 4e-7  # relative accuracy near 0 too (no cancellation)
    assert torch.equal(torch.sign(y), torch.sign(ref))
    assert float(y.abs().max()) <= 1.0


def _cpu_flags() -> set[str]:
    try:
        text = open("/proc/cpuinfo").read()
    except OSError:
        return set()
    return set(
        next(
            (ln.split(":", 1)[1].split() for ln in text.splitlines() if ln.startswith("flags")), []
        )
    )


@pytest.mark.slow
@pytest.mark.skipif(not {"avx2", "fma"} <= _cpu_flags(), reason="needs a CPU with AVX2 and FMA")
def test_the_avx2_path_matches_torch_as_the_native_one(tmp_path, monkeypatch):
    """The code path of an AVX2-only CPU (8-float vectors, 4 x 2 register blocks), built here with
    -march=haswell whatever this CPU has: another library, and the same accuracy checks as the
    native build (tanh, the update against the torch path, seeding independent of threads)."""
    native.build.cache_clear()
    native.load.cache_clear()
    try:
        monkeypatch.setenv("LHF_HF_KERNEL_CACHE", str(tmp_path))
        native_lib = native.build(64)
        monkeypatch.setenv("LHF_HF_KERNEL_MARCH", "haswell")
        native.build.cache_clear()
        assert native.build(64) != native_lib
        assert native.load(64).lhf_vector_width() == 8
        test_tanh_matches_float64_tanh()
        test_kernel_equals_torch_update_over_many_steps()
        test_kernel_permutations_are_seeded_and_independent_of_threads()
        monkeypatch.setenv("LHF_HF_KERNEL_MARCH", "native; rm -rf x")  # never reaches a shell
        native.build.cache_clear()
        with pytest.raises(native.KernelUnavailable, match="must be a -march name"):
            native.build(64)
        monkeypatch.setenv("LHF_HF_KERNEL_MARCH", "no-such-cpu")  # the compiler's refusal
        native.build.cache_clear()
        with pytest.raises(
            native.KernelUnavailable, match=r"-march=no-such-cpu \(\$LHF_HF_KERNEL_MARCH\)"
        ):
            native.build(64)
        monkeypatch.setenv("LHF_HF_KERNEL_MARCH", "")  # empty: as if unset
        native.build.cache_clear()
        assert native.target_march() == "native" and native.build(64) == native_lib
    finally:
        native.build.cache_clear()
        native.load.cache_clear()


def _update(gradients, L=3, N=200, epochs=2, batch=25, permutations=None, seed=5, threads=None):
    policy = StackedPolicy(L, 2, 5, torch.Generator().manual_seed(4))
    opt = make_optimizer(policy, 3e-4)
    data = random_rollout(L, N, seed=2)
    old = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        ppo_update(
            policy,
            opt,
            data,
            epochs,
            batch,
            permutations=permutations,
            generator=torch.Generator().manual_seed(seed),
            gradients=gradients,
        )
    finally:
        torch.set_num_threads(old)
    return policy, opt


@pytest.mark.slow
def test_kernel_equals_torch_update_over_many_steps():
    """Same permutations: two epochs of 8 minibatch steps (incl. a last, shorter minibatch: 200 = 8 x
    24 + 8) stay within float rounding of the torch path, and the Adam state matches too."""
    g = torch.Generator().manual_seed(0)
    perms = [torch.argsort(torch.rand(3, 200, generator=g), dim=1) for _ in range(2)]
    out = {m: _update(m, batch=24, permutations=perms) for m in ("manual", "kernel")}
    (p_m, o_m), (p_k, o_k) = out["manual"], out["kernel"]
    for a, b in zip(p_m.parameters(), p_k.parameters(), strict=True):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=2e-6)
    for a, b in zip(p_m.parameters(), p_k.parameters(), strict=True):
        sa, sb = o_m.state[a], o_k.state[b]
        assert float(sa["step"]) == float(sb["step"]) == 18
        torch.testing.assert_close(sb["exp_avg"], sa["exp_avg"], rtol=1e-4, atol=1e-6)
        torch.testing.assert_close(sb["exp_avg_sq"], sa["exp_avg_sq"], rtol=1e-3, atol=1e-10)
    # the padded critic head columns stay exactly zero
    assert float(p_k.net.weights[2].detach()[3:, :, 1:].abs().max()) == 0.0


def test_kernel_permutations_are_seeded_and_independent_of_threads():
    a, _ = _update("kernel", L=5, threads=1)
    b, _ = _update("kernel", L=5, threads=2)
    c, _ = _update("kernel", L=5, threads=2, seed=6)
    for x, y in zip(a.parameters(), b.parameters(), strict=True):
        assert torch.equal(x, y)
    assert any(not torch.equal(x, z) for x, z in zip(a.parameters(), c.parameters(), strict=True))


def test_kernel_update_continues_from_torch_adam_state():
    """The kernel reads and writes torch's own Adam state: torch step, then kernel step = two torch
    steps (same permutations)."""
    g = torch.Generator().manual_seed(1)
    perms = [torch.argsort(torch.rand(3, 200, generator=g), dim=1)]
    data = random_rollout(3, 200, seed=2)
    results = []
    for second in ("manual", "kernel"):
        policy = StackedPolicy(3, 2, 5, torch.Generator().manual_seed(4))
        opt = make_optimizer(policy, 3e-4)
        ppo_update(policy, opt, data, 1, 50, permutations=perms, gradients="manual")
        ppo_update(policy, opt, data, 1, 50, permutations=perms, gradients=second)
        assert all(float(st["step"]) == 8 for st in opt.state.values())
        results.append([p.detach().clone() for p in policy.parameters()])
    for a, b in zip(*results, strict=True):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=2e-6)


def test_kernel_errors():
    policy = StackedPolicy(2, 2, 5, torch.Generator())
    data = random_rollout(2, 40)
    bad = random_rollout(2, 40)
    bad.actions[1, 3] = 5
    with pytest.raises(RuntimeError, match="action is out of range"):
        ppo_update(policy, make_optimizer(policy, 3e-4), bad, 1, 10, gradients="kernel")
    perm = torch.arange(40).expand(2, -1).clone()
    perm[0, 0] = 40
    with pytest.raises(RuntimeError, match="permutation index is out of range"):
        ppo_update(policy, make_optimizer(policy, 3e-4), data, 1, 10, [perm], gradients="kernel")
    with pytest.raises(ValueError, match="permutations: expected 2"):
        ppo_update(policy, make_optimizer(policy, 3e-4), data, 2, 10, [perm], gradients="kernel")
    p64 = StackedPolicy(2, 2, 5, torch.Generator()).double()
    with pytest.raises(native.KernelUnavailable, match="float32 CPU"):
        ppo_update(p64, make_optimizer(p64, 3e-4), data, 1, 10, gradients="kernel")
    sgd = torch.optim.SGD(policy.parameters(), lr=0.1)
    with pytest.raises(native.KernelUnavailable, match="Adam"):
        ppo_update(policy, sgd, data, 1, 10, gradients="kernel")


def test_no_compiler_is_a_clear_error_and_auto_falls_back(tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("LHF_HF_KERNEL_CACHE", str(tmp_path))
    monkeypatch.setenv("CXX", "no-such-compiler-lhf")
    native.build.cache_clear()
    native.load.cache_clear()
    try:
        policy = StackedPolicy(2, 2, 5, torch.Generator().manual_seed(0))
        data = random_rollout(2, 40)
        with pytest.raises(native.KernelUnavailable, match="no C\\+\\+ compiler"):
            ppo_update(policy, make_optimizer(policy, 3e-4), data, 1, 10, gradients="kernel")
        before = [p.detach().clone() for p in policy.parameters()]
        with caplog.at_level(logging.WARNING):
            ppo_update(policy, make_optimizer(policy, 3e-4), data, 1, 10, gradients="auto")
        assert "torch ops instead" in caplog.text
        assert any(not torch.equal(a, b) for a, b in zip(before, policy.parameters(), strict=True))
    finally:
        native.build.cache_clear()
        native.load.cache_clear()


@pytest.mark.slow
def test_collect_config_ppo_backend(monkeypatch, tmp_path):
    from lhf_hf.collection.batched_collector import resolve_ppo_backend
    from lhf_hf.configs import CollectConfig

    kw = dict(env_id="darkroom", tasks="0", histories=2, steps=100, collector="batched")
    with pytest.raises(ValueError, match="ppo_backend must be one of"):
        CollectConfig(**kw, ppo_backend="fast")
    with pytest.raises(ValueError, match="runs on the CPU"):
        CollectConfig(**kw, ppo_backend="kernel", device="cuda")
    cfg = CollectConfig(**kw)
    monkeypatch.setenv("LHF_HF_KERNEL_CACHE", str(tmp_path / "k"))
    native.build.cache_clear()
    native.load.cache_clear()
    from lhf_hf.collection import backend_verdict

    # auto: the backend measured faster here (kernel on AVX-512 Intel, torch on some AVX2 CPUs)
    assert resolve_ppo_backend(cfg) == backend_verdict.verdict(2, 5)["choice"]
    cfg.ppo_backend = "kernel"
    assert cfg.identity()["ppo_backend"] == "kernel"
    cfg.ppo_backend = "torch"
    assert "ppo_backend" not in cfg.identity()  # as in datasets made before the field existed
    monkeypatch.setenv("LHF_HF_KERNEL_CACHE", str(tmp_path))
    monkeypatch.setenv("CXX", "no-such-compiler-lhf")
    native.build.cache_clear()
    native.load.cache_clear()
    try:
        assert resolve_ppo_backend(CollectConfig(**kw)) == "torch"
        with pytest.raises(native.KernelUnavailable):
            resolve_ppo_backend(CollectConfig(**kw, ppo_backend="kernel"))
    finally:
        native.build.cache_clear()
        native.load.cache_clear()


def test_kernel_rollout_shapes_are_checked_by_torch_layout():
    """Non-contiguous rollout tensors (e.g. views) are made contiguous before the call."""
    data = random_rollout(2, 40)
    data.obs = data.obs.transpose(0, 1).contiguous().transpose(0, 1)  # (L, N, d), not contiguous
    assert not data.obs.is_contiguous()
    ref = random_rollout(2, 40)
    perm = [torch.arange(40).expand(2, -1).contiguous()]
    out = []
    for d in (data, ref):
        policy = StackedPolicy(2, 2, 5, torch.Generator().manual_seed(0))
        ppo_update(policy, make_optimizer(policy, 3e-4), d, 1, 10, perm, gradients="kernel")
        out.append([p.detach().clone() for p in policy.parameters()])
    for a, b in zip(*out, strict=True):
        assert torch.equal(a, b)
    assert np.isfinite(out[0][0].numpy()).all()


def test_kernel_act_equals_torch_policy():
    """Values and log-probs equal the torch forward's; actions are the inverse CDF of the policy at
    the given uniforms (rows whose uniform lies within float rounding of a CDF step excepted)."""
    L, E = 3, 150  # E > 64: several row blocks and a partial one
    policy = StackedPolicy(L, 3, 5, torch.Generator().manual_seed(2))
    with torch.no_grad():  # sharper policies than at initialisation
        policy.net.weights[2].mul_(300.0)
    obs = torch.randint(0, 9, (L, E, 3)).float()
    u = torch.rand(L, E, generator=torch.Generator().manual_seed(3))
    actions, logp, values = native.ppo_act(policy.stacked_params(), obs, u)
    with torch.no_grad():
        logits, ref_values = policy(obs)
        logp_all = torch.log_softmax(logits.double(), -1)
    # float32 sums in another order; the sharpened head makes logits of ~10
    torch.testing.assert_close(values, ref_values, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(
        logp.double(), logp_all.gather(-1, actions[..., None])[..., 0], rtol=1e-4, atol=1e-4
    )
    cdf = logp_all.exp().cumsum(-1)  # (L, E, A)
    expected = (u.double()[..., None] >= cdf).sum(-1).clamp_max(4)
    near_step = ((u.double()[..., None] - cdf).abs() < 1e-4).any(-1)
    assert bool(((actions == expected) | near_step).all())
    assert len(set(actions.flatten().tolist())) > 1
    none_a, none_lp, only_values = native.ppo_act(policy.stacked_params(), obs, None)
    assert none_a is None and none_lp is None and torch.equal(only_values, values)
    with pytest.raises(ValueError, match="uniforms: expected shape"):
        native.ppo_act(policy.stacked_params(), obs, u[:, :10])
