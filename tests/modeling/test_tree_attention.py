"""The planner's tree attention kernel (``tree_attention``): outputs equal the torch reference's on
explicit paths, depth after depth as the kernel builds each beam's path from its parent; head dims 8
and 16, grouped-query attention, contexts off the vector width; the same bits at any thread count;
the errors it raises and the cases it refuses."""

from __future__ import annotations

import pytest
import torch

from lhf_hf.modeling import tree_attention
from lhf_hf.utils.native_build import KernelUnavailable

from .test_attention_kernel import _cpu_flags

try:
    tree_attention.load()
    NO_KERNEL = None
except KernelUnavailable as exc:  # no compiler here: the planner's torch engine runs (tested)
    NO_KERNEL = str(exc)
pytestmark = pytest.mark.skipif(NO_KERNEL is not None, reason=f"no kernel: {NO_KERNEL}")


def _search(B, H, Hkv, d, L0, depths, A=3, beams=4, seed=0, threads=None):
    """A beam search's attention calls with random queries, keys, values and selections: the
    kernel's outputs and the reference's on explicitly kept paths, per depth."""
    g = torch.Generator().manual_seed(seed)
    k_ctx, v_ctx = torch.randn(2, B, Hkv, L0, d, generator=g)
    kct, vct = tree_attention.transposed(k_ctx), tree_attention.transposed(v_ctx)
    path_max = max(2 * depths - 3, 0)
    bufs = [tree_attention.path_buffers(B, Hkv, beams, d, path_max + 1 + A) for _ in range(2)]
    for buf in (t for pair in bufs for t in pair):  # uninitialised memory may hold NaN: never read
        buf.fill_(float("nan"))
    paths_k = paths_v = torch.zeros(B, 1, 0, Hkv, d)  # the reference's paths (B, nb, plen, Hkv, d)
    parent = src_col = None
    plen, nb, got, want = 0, 1, [], []
    saved = torch.get_num_threads()
    torch.set_num_threads(threads or saved)
    try:
        for depth in range(depths):
            shared = int(depth > 0)
            per_beam = A + shared
            n = nb * per_beam
            q = torch.randn(B, n, H, d, generator=g)
            # keys and values as strided views, the planner's layout (a slice of a projection)
            kv = torch.randn(B, n, 3 * Hkv, d, generator=g)
            k, v = kv[:, :, Hkv : 2 * Hkv], kv[:, :, 2 * Hkv :]
            ctx_lo = torch.randint(0, L0 + 1, (n,), generator=g)
            src = bufs[(depth + 1) % 2] if plen else None
            out = tree_attention.forward(q, k, v, kct, vct, L0, src, bufs[depth % 2], parent,
                                         src_col, plen, ctx_lo, per_beam, shared, 0.3)  # fmt: skip
            ref = tree_attention.reference(q, k, v, k_ctx, v_ctx, paths_k, paths_v, ctx_lo,
                                           per_beam, shared, 0.3)  # fmt: skip
            got.append(out)
            want.append(ref)
            # the kernel's path buffers hold each beam's path, then its group's new tokens
            for buf, path, new in (
                (bufs[depth % 2][0], paths_k, k),
                (bufs[depth % 2][1], paths_v, v),
            ):
                kept = tree_attention.read_paths(buf, nb, plen + per_beam)
                expect = torch.cat([path, new.reshape(B, nb, per_beam, Hkv, d)], dim=2)
                assert torch.equal(kept, expect)
            # select: every kept beam continues a random beam through one of its query tokens
            keep = min(beams, nb * A)
            parent = torch.randint(0, nb, (B, keep), generator=g)
            token = shared + torch.randint(0, A, (B, keep), generator=g)
            b = torch.arange(B)[:, None]
            group_k = k.reshape(B, nb, per_beam, Hkv, d)[b, parent]  # (B, keep, per_beam, Hkv, d)
            group_v = v.reshape(B, nb, per_beam, Hkv, d)[b, parent]
            paths_k = torch.cat([paths_k[b, parent], group_k[:, :, :shared],
                                 group_k[b, torch.arange(keep), token][:, :, None]], dim=2)  # fmt: skip
            paths_v = torch.cat([paths_v[b, parent], group_v[:, :, :shared],
                                 group_v[b, torch.arange(keep), token][:, :, None]], dim=2)  # fmt: skip
            src_col = plen + token
            plen, nb = plen + shared + 1, keep
    finally:
        torch.set_num_threads(saved)
    return got, want


@pytest.mark.parametrize(
    "B, H, Hkv, d, L0",
    [(2, 4, 4, 8, 37), (3, 2, 1, 8, 16), (2, 4, 2, 16, 53), (1, 2, 2, 16, 5), (2, 2, 2, 8, 0)],
)
def test_outputs_equal_the_reference_depth_after_depth(B, H, Hkv, d, L0):
    """Contexts off the vector width (37, 53, 5), exactly one vector (16) and none (0); GQA
    (Hkv < H); five depths, so paths pass through two generations of buffers and back."""
    got, want = _search(B, H, Hkv, d, L0, depths=5)
    for depth, (a, b) in enumerate(zip(got, want, strict=True)):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=2e-6, msg=f"depth {depth}")


def test_results_do_not_depend_on_threads():
    one, _ = _search(3, 4, 2, 8, 41, depths=4, threads=1)
    two, _ = _search(3, 4, 2, 8, 41, depths=4, threads=2)
    assert all(torch.equal(a, b) for a, b in zip(one, two, strict=True))


def test_errors_name_what_is_wrong():
    B, H, d, L0, n = 1, 2, 8, 10, 3
    q = torch.randn(B, n, H, d)
    kct = vct = tree_attention.transposed(torch.randn(B, H, L0, d))
    bufs = [tree_attention.path_buffers(B, H, 2, d, 8) for _ in range(2)]
    lo = torch.zeros(n, dtype=torch.int32)
    args = dict(kct=kct, vct=vct, L0=L0, ctx_lo=lo, per_beam=n, shared=0, scale=1.0)
    with pytest.raises(RuntimeError, match="head dim"):  # no compiled path for head dim 4
        q4 = torch.randn(B, n, H, 4)
        k4 = tree_attention.transposed(torch.randn(B, H, L0, 4))
        b4 = tree_attention.path_buffers(B, H, 2, 4, 8)
        tree_attention.forward(q4, q4, q4, k4, k4, L0, None, b4, None, None, 0, lo, n, 0, 1.0)
    with pytest.raises(RuntimeError, match="out of bounds"):
        tree_attention.forward(q, q, q, **{**args, "ctx_lo": lo + L0 + 1},
                               src=None, dst=bufs[0], parent=None, src_col=None, plen=0)  # fmt: skip
    parent = torch.full((B, 1), 2)  # beam slot 2 of 2
    with pytest.raises(RuntimeError, match="out of bounds"):
        tree_attention.forward(q, q, q, **args, src=bufs[0], dst=bufs[1], parent=parent,
                               src_col=torch.ones(B, 1), plen=1)  # fmt: skip
    with pytest.raises(ValueError, match="needs src, parent and src_col"):
        tree_attention.forward(q, q, q, **args, src=None, dst=bufs[1], parent=None, src_col=None,
                               plen=1)  # fmt: skip
    with pytest.raises(ValueError, match="d contiguous"):
        tree_attention.forward(q.transpose(2, 3), q, q, **args, src=None, dst=bufs[0],
                               parent=None, src_col=None, plen=0)  # fmt: skip


def test_unsupported_cases_say_why(monkeypatch, tmp_path):
    cpu = torch.device("cpu")
    assert tree_attention.unsupported(8, torch.float32, cpu) is None
    assert "head dims (8, 16), this model 4" in tree_attention.unsupported(4, torch.float32, cpu)
    assert "float32 (the model is torch.float64)" in tree_attention.unsupported(
        8, torch.float64, cpu
    )
    assert "runs on the CPU" in tree_attention.unsupported(8, torch.float32, torch.device("cuda"))
    tree_attention.build.cache_clear()
    tree_attention.load.cache_clear()
    try:
        with monkeypatch.context() as m:
            m.setenv("LHF_HF_KERNEL_CACHE", str(tmp_path))
            m.setenv("CXX", "no-such-compiler-lhf")
            assert "no C++ compiler 'no-such-compiler-lhf'" in tree_attention.unsupported(
                8, torch.float32, cpu
            )
    finally:
        tree_attention.build.cache_clear()
        tree_attention.load.cache_clear()


@pytest.mark.slow
@pytest.mark.skipif(not {"avx2", "fma"} <= _cpu_flags(), reason="needs a CPU with AVX2 and FMA")
def test_the_avx2_path_equals_the_reference_as_the_native_one(tmp_path, monkeypatch):
    """The code path of an AVX2-only CPU (8-float vectors), built here with -march=haswell."""
    tree_attention.build.cache_clear()
    tree_attention.load.cache_clear()
    try:
        monkeypatch.setenv("LHF_HF_KERNEL_CACHE", str(tmp_path))
        monkeypatch.setenv("LHF_HF_KERNEL_MARCH", "haswell")
        assert tree_attention.load().lhf_tree_vector_width() == 8
        for shape in [(2, 4, 2, 8, 37), (2, 2, 2, 16, 19), (1, 2, 1, 8, 8)]:
            test_outputs_equal_the_reference_depth_after_depth(*shape)
    finally:
        tree_attention.build.cache_clear()
        tree_attention.load.cache_clear()
