"""The C++ training attention (``lhf_kernel``): outputs and gradients equal the torch reference's
(``train_attention.DropoutAttention``, autograd-checked there) given the same mask and the same
dropout mask, materialised from the kernel's counter stream; the mask's rate, independence and
reproducibility; its exp's error; the cases it leaves to the torch path; the whole model."""

from __future__ import annotations

import pytest
import torch

from lhf_hf.modeling import ICRLModel, attention_kernel, train_attention
from lhf_hf.modeling.attention import band_mask
from lhf_hf.modeling.attention_kernel import KernelAttention, drop_probability, keep_mask
from lhf_hf.modeling.train_attention import DropoutAttention
from lhf_hf.utils.native_build import KernelUnavailable

from .test_modeling_icrl import grid_config, make_batch

try:
    attention_kernel.load()
    NO_KERNEL = None
except KernelUnavailable as exc:  # no compiler here: the torch path trains (tested elsewhere)
    NO_KERNEL = str(exc)
pytestmark = pytest.mark.skipif(NO_KERNEL is not None, reason=f"no kernel: {NO_KERNEL}")


class _Module(torch.nn.Module):
    def __init__(self, causal=True):
        super().__init__()
        self.num_key_value_groups, self.is_causal = 1, causal


def qkv(B, H, L, D, seed=0):
    """(B, H, L, D) views of (B, L, H, D) tensors, as the Llama projections give them."""
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(B, L, H, D, generator=g).transpose(1, 2).requires_grad_() for _ in range(3)]


def ranges(kind: str, L: int, window: int = 7):
    """(lo, hi) int32 key ranges and the (L, L) additive bias that allows exactly them."""
    hi = torch.arange(1, L + 1, dtype=torch.int32)
    if kind == "causal":
        lo = torch.zeros(L, dtype=torch.int32)
    elif kind == "band":
        lo = (hi - window).clamp_min(0).to(torch.int32)
    else:  # every key
        lo, hi = torch.zeros(L, dtype=torch.int32), torch.full((L,), L, dtype=torch.int32)
    j = torch.arange(L)
    allowed = (j >= lo[:, None]) & (j < hi[:, None])
    return lo, hi, torch.zeros(L, L).masked_fill_(~allowed, float("-inf"))


def reference(q, k, v, bias, scale, p, seed):
    """The torch path's formula with the kernel's dropout mask: (B, L, H, D)."""
    B, H, L, _ = q.shape
    keep = torch.ones(B, H, L, L)
    if p > 0:
        keep = keep_mask(B, H, L, p, seed).float() / (1 - drop_probability(p))
    return DropoutAttention.apply(q * scale, k, v, bias, keep, True).transpose(1, 2)


@pytest.mark.parametrize("kind", ["causal", "band", "full"])
@pytest.mark.parametrize("p", [0.0, 0.1])
@pytest.mark.parametrize(
    "B, H, L, D", [(2, 3, 37, 8), (1, 2, 1, 8), (3, 1, 16, 16), (2, 4, 53, 16)]
)
def test_outputs_and_gradients_equal_the_reference(kind, p, B, H, L, D):
    """Lengths off the vector width (37, 53), one query, exactly one vector (16); head dims 8, 16."""
    q, k, v = qkv(B, H, L, D)
    lo, hi, bias = ranges(kind, L)
    seed = 0x9E3779B97F4A7C15
    out = KernelAttention.apply(q, k, v, lo, hi, D**-0.5, p, seed)
    ref = reference(q, k, v, bias, D**-0.5, p, seed)
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=2e-6)
    g = torch.randn(out.shape, generator=torch.Generator().manual_seed(1))
    grads = torch.autograd.grad(out, (q, k, v), g)
    ref_grads = torch.autograd.grad(ref, (q, k, v), g)
    for name, a, b in zip("qkv", grads, ref_grads, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=5e-6, msg=f"d{name}")


def test_a_row_without_keys_gives_zero_and_no_gradient():
    q, k, v = qkv(2, 2, 9, 8)
    lo, hi, _ = ranges("causal", 9)
    lo[4], hi[4] = 3, 3  # query 4 sees nothing
    out = KernelAttention.apply(q, k, v, lo, hi, 0.3, 0.1, 5)
    assert out[:, 4].abs().max() == 0 and out[:, 5].abs().max() > 0
    (dq,) = torch.autograd.grad(out.sum(), (q,))
    assert dq[:, :, 4].abs().max() == 0


def test_the_mask_keeps_the_papers_rate_and_is_reproducible_from_the_seed():
    B, H, L, p = 16, 4, 200, 0.1  # the paper's attention dropout
    m = keep_mask(B, H, L, p, seed=7)
    n = m.numel()
    rate = m.float().mean().item()
    assert abs(rate - (1 - p)) < 5 * (p * (1 - p) / n) ** 0.5  # 5 sigma of a binomial
    per_head = m.float().mean((2, 3))  # (B, H): every head, not just the total
    assert (per_head - (1 - p)).abs().max() < 5 * (p * (1 - p) / L**2) ** 0.5
    assert torch.equal(m, keep_mask(B, H, L, p, seed=7))
    other = keep_mask(B, H, L, p, seed=8)
    assert not torch.equal(m, other)
    assert drop_probability(p) == pytest.approx(p, abs=2**-32)


def test_the_mask_is_uncorrelated_across_heads_rows_keys_and_seeds():
    p = 0.5  # the most bits per weight to compare
    m = keep_mask(8, 4, 128, p, seed=3).float() * 2 - 1  # (B, H, L, L): +-1, mean ~0

    def independent(a, b) -> bool:
        """mean(a * b) of +-1 products is within 5 sigma (1 / sqrt(n)) of 0."""
        return abs((a * b).mean().item()) < 5 / a.numel() ** 0.5

    assert independent(m[:, 0], m[:, 1])  # head 0 vs head 1
    assert independent(m[0], m[1])  # batch 0 vs 1
    assert independent(m[..., 1:, :], m[..., :-1, :])  # neighbouring rows
    assert independent(m[..., 1:], m[..., :-1])  # neighbouring keys
    assert independent(m[..., 16:], m[..., :-16])  # one AVX-512 vector apart
    assert independent(m[..., 1:, :-1], m[..., :-1, 1:])  # (i, j + 1) vs (i + 1, j)
    assert independent(m, keep_mask(8, 4, 128, p, seed=4).float() * 2 - 1)  # seeds


def test_results_do_not_depend_on_threads():
    q, k, v = qkv(4, 4, 40, 8)
    lo, hi, _ = ranges("causal", 40)
    saved = torch.get_num_threads()
    results = []
    try:
        for threads in (1, 2, 3):
            torch.set_num_threads(threads)
            out = KernelAttention.apply(q, k, v, lo, hi, 0.35, 0.1, 11)
            results.append((out, *torch.autograd.grad(out.square().sum(), (q, k, v))))
    finally:
        torch.set_num_threads(saved)
    for other in results[1:]:
        for a, b in zip(results[0], other, strict=True):
            assert torch.equal(a, b)


def test_exp_relative_error():
    x = torch.cat(
        [
            -torch.linspace(0, 87, 1_000_001),
            -torch.logspace(-10, 0, 1001),
            torch.tensor([0.0, -0.0, -87.3, -88.0, -1e30, float("-inf")]),
        ]
    )  # odd length: the tail too
    y = attention_kernel.kernel_exp(x).double()
    ref = torch.exp(x.double())
    normal = x > -87.0
    rel = ((y - ref) / ref)[normal].abs()
    # Cephes' degree-5 expf polynomial after a Cody-Waite reduction: a few float ulps
    assert float(rel.max()) < 3e-7
    assert y[x <= -87.3].eq(0).all()  # below the normal floats (and masked keys): exactly 0
    assert y[x == 0].eq(1).all()


def test_masks_read_as_ranges():
    L = 12
    causal = attention_kernel.key_ranges(None, L)
    assert causal[0].eq(0).all() and torch.equal(causal[1], torch.arange(1, L + 1).int())
    pos = torch.arange(L)
    band = band_mask(pos, torch.full((L,), 5), pos).expand(3, 1, L, L)  # as ICRLModel builds it
    lo, hi = attention_kernel.key_ranges(band, L)
    assert torch.equal(lo, (pos - 4).clamp_min(0).int()) and torch.equal(hi, (pos + 1).int())
    assert attention_kernel.key_ranges(torch.isfinite(band), L) is not None  # a bool mask
    holes = torch.isfinite(band).clone()
    holes[..., 6, 4] = False  # not a range
    assert attention_kernel.key_ranges(holes, L) is None
    assert attention_kernel.key_ranges(band.clone(), L) is not None  # materialised, still shared
    per_batch = band.clone()
    per_batch[1, 0, 5, 5] = float("-inf")  # not shared by the batch (padding)
    assert attention_kernel.key_ranges(per_batch, L) is None
    weighted = band[:1].clone()
    weighted[..., 3, 2] = -1.0  # a bias other than 0 / -inf
    assert attention_kernel.key_ranges(weighted, L) is None


@pytest.mark.parametrize("mask_kind", ["causal", "band", "bool", "none"])
def test_the_interface_equals_the_torch_path(mask_kind):
    """``attention_forward`` as transformers calls it: without dropout the torch path's numbers;
    with dropout the reference with the mask of the seed it drew from torch's generator."""
    B, H, L, D = 2, 4, 21, 8
    q, k, v = qkv(B, H, L, D)
    pos = torch.arange(L)
    module, mask = _Module(), None
    if mask_kind in ("band", "bool"):
        mask = band_mask(pos, torch.full((L,), 6), pos).expand(B, 1, L, L)
        mask = torch.isfinite(mask) if mask_kind == "bool" else mask
    elif mask_kind == "none":
        module = _Module(causal=False)
    out, _ = attention_kernel.attention_forward(module, q, k, v, mask, dropout=0.0)
    ref, _ = train_attention.attention_forward(module, q, k, v, mask, dropout=0.0)
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=2e-6)

    torch.manual_seed(3)
    out, _ = attention_kernel.attention_forward(module, q, k, v, mask, dropout=0.1)
    torch.manual_seed(3)
    seed = int(torch.randint(-(2**63), 2**63 - 1, (), dtype=torch.int64)) % 2**64
    if mask_kind == "causal":
        bias = ranges("causal", L)[2]
    elif mask_kind == "none":
        bias = torch.zeros(L, L)
    else:
        bias = band_mask(pos, torch.full((L,), 6), pos)
    torch.testing.assert_close(
        out, reference(q, k, v, bias, D**-0.5, 0.1, seed), rtol=1e-5, atol=2e-6
    )


def test_cases_left_to_the_torch_path_are_the_torch_path():
    B, H, L = 2, 2, 6
    module = _Module()
    cases = {
        "float64": [t.double() for t in qkv(B, H, L, 8)],
        "head dim 4": qkv(B, H, L, 4),
        "a KV cache": [qkv(B, H, 2, 8)[0], *qkv(B, H, L, 8)[1:]],
    }
    for name, (q, k, v) in cases.items():
        out, _ = attention_kernel.attention_forward(module, q, k, v, None, dropout=0.0)
        ref, _ = train_attention.attention_forward(module, q, k, v, None, dropout=0.0)
        assert torch.equal(out, ref), name
    q, k, v = qkv(B, H, L, 8)
    per_batch = torch.zeros(B, 1, L, L)
    per_batch[1, 0, :, 0] = float("-inf")  # a mask per batch element: not a shared range
    out, _ = attention_kernel.attention_forward(module, q, k, v, per_batch, dropout=0.0)
    ref, _ = train_attention.attention_forward(module, q, k, v, per_batch, dropout=0.0)
    assert torch.equal(out, ref)


def _models(objective: str, **kw):
    torch.manual_seed(0)
    ours = ICRLModel(grid_config(objective, embedding_dropout=0.0, **kw)).train()
    ours.config._attn_implementation = attention_kernel.NAME
    torch.manual_seed(0)
    ref = ICRLModel(grid_config(objective, embedding_dropout=0.0, **kw)).train()  # lhf_sdpa
    assert ref.config._attn_implementation == train_attention.NAME
    return ours, ref


def _loss_and_grads(model, batch, seed):
    model.zero_grad()
    torch.manual_seed(seed)
    loss = model(**batch).loss
    loss.backward()
    return loss.detach(), {
        n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None
    }


@pytest.mark.parametrize("objective", ["ad", "dicp"])
@pytest.mark.parametrize("attention", ["window", "band"])
def test_the_model_trains_as_with_the_torch_path_without_dropout(objective, attention):
    ours, ref = _models(objective, attention=attention, attention_dropout=0.0)
    batch, actions = make_batch(ours.config)
    batch["action_labels"] = actions
    if attention == "band":  # sequences longer than the context: the band mask
        ours.config.context_length = ref.config.context_length = 3
    loss, grads = _loss_and_grads(ours, batch, 0)
    ref_loss, ref_grads = _loss_and_grads(ref, batch, 0)
    torch.testing.assert_close(loss, ref_loss, rtol=1e-5, atol=1e-6)
    assert grads.keys() == ref_grads.keys()
    for name in grads:
        torch.testing.assert_close(grads[name], ref_grads[name], rtol=1e-4, atol=1e-6, msg=name)


@pytest.mark.parametrize("objective", ["ad", "dicp"])
def test_the_model_with_dropout_equals_the_torch_path_given_the_kernels_masks(
    objective, monkeypatch
):
    """Training with the paper's dropout: the torch path given, layer by layer, the masks the kernel
    drew (recorded from its seeds) computes the same loss and gradients; one seed is one run."""
    ours, ref = _models(objective, attention_dropout=0.1)
    batch, actions = make_batch(ours.config)
    batch["action_labels"] = actions
    seeds = []
    apply = KernelAttention.apply

    def recording(q, k, v, lo, hi, scale, p, seed):
        seeds.append(seed)
        return apply(q, k, v, lo, hi, scale, p, seed)

    monkeypatch.setattr(KernelAttention, "apply", recording)
    loss, grads = _loss_and_grads(ours, batch, 5)
    assert len(seeds) == ours.config.num_hidden_layers and len(set(seeds)) == len(seeds)
    again_loss, again = _loss_and_grads(ours, batch, 5)  # the same seed: the same step
    assert torch.equal(loss, again_loss) and all(torch.equal(grads[n], again[n]) for n in grads)
    other_loss, _ = _loss_and_grads(ours, batch, 6)
    assert not torch.equal(loss, other_loss)

    masks = iter(seeds[: ours.config.num_hidden_layers])

    def with_kernel_mask(shape, p):
        B, H, L, _ = shape
        keep = keep_mask(B, H, L, p, next(masks)).float() / (1 - drop_probability(p))
        return keep, drop_probability(p)

    monkeypatch.setattr(train_attention, "keep_weights", with_kernel_mask)
    ref_loss, ref_grads = _loss_and_grads(ref, batch, 5)
    torch.testing.assert_close(loss, ref_loss, rtol=1e-5, atol=1e-6)
    for name in grads:
        torch.testing.assert_close(grads[name], ref_grads[name], rtol=1e-4, atol=1e-6, msg=name)


def _cpu_flags() -> set[str]:
    try:
        text = open("/proc/cpuinfo").read()
    except OSError:
        return set()
    line = next((ln for ln in text.splitlines() if ln.startswith("flags")), "flags:")
    return set(line.split(":", 1)[1].split())


@pytest.mark.slow
@pytest.mark.skipif(not {"avx2", "fma"} <= _cpu_flags(), reason="needs a CPU with AVX2 and FMA")
def test_the_avx2_path_equals_the_reference_as_the_native_one(tmp_path, monkeypatch):
    """The code path of an AVX2-only CPU (8-float vectors), built here with -march=haswell: another
    library, the same outputs, gradients, exp accuracy and the same dropout mask bit for bit (the
    hash does not depend on the vector width)."""
    attention_kernel.build.cache_clear()
    attention_kernel.load.cache_clear()
    try:
        monkeypatch.setenv("LHF_HF_KERNEL_CACHE", str(tmp_path))
        native_lib = attention_kernel.build()
        native_mask = keep_mask(2, 3, 45, 0.1, seed=9)
        monkeypatch.setenv("LHF_HF_KERNEL_MARCH", "haswell")
        attention_kernel.build.cache_clear()
        attention_kernel.load.cache_clear()
        assert attention_kernel.build() != native_lib
        assert attention_kernel.load().lhf_attn_vector_width() == 8
        assert torch.equal(keep_mask(2, 3, 45, 0.1, seed=9), native_mask)
        for kind in ("causal", "band", "full"):
            for p in (0.0, 0.1):
                for shape in [(2, 3, 37, 8), (2, 2, 19, 16)]:
                    test_outputs_and_gradients_equal_the_reference(kind, p, *shape)
        test_exp_relative_error()
        test_results_do_not_depend_on_threads()
    finally:
        attention_kernel.build.cache_clear()
        attention_kernel.load.cache_clear()


def test_no_compiler_means_no_kernel_and_auto_trains_with_torch(monkeypatch, tmp_path):
    from lhf_hf.configs import TrainConfig
    from lhf_hf.errors import UserError
    from lhf_hf.training.attention_backend import resolve_attention_kernel

    def cfg(choice):
        return TrainConfig(dataset="d", objective="ad", out="o", attention_kernel=choice)

    config, cpu = grid_config("ad", attention_dropout=0.1), torch.device("cpu")
    attention_kernel.build.cache_clear()
    attention_kernel.load.cache_clear()
    try:
        with monkeypatch.context() as m:
            m.setenv("LHF_HF_KERNEL_CACHE", str(tmp_path))
            m.setenv("CXX", "no-such-compiler-lhf")
            assert "no C++ compiler 'no-such-compiler-lhf'" in attention_kernel.available()
            assert resolve_attention_kernel(cfg("auto"), config, cpu) == "torch"
            assert resolve_attention_kernel(cfg("torch"), config, cpu) == "torch"
            with pytest.raises(UserError, match="attention_kernel='kernel': no C.. compiler"):
                resolve_attention_kernel(cfg("kernel"), config, cpu)
    finally:
        attention_kernel.build.cache_clear()
        attention_kernel.load.cache_clear()
    config = grid_config("ad")
    assert resolve_attention_kernel(cfg("auto"), config, torch.device("cpu")) == "kernel"
    assert resolve_attention_kernel(cfg("auto"), config, torch.device("cuda")) == "torch"
    head_dim_4 = grid_config("ad", num_attention_heads=4)  # hidden 16 / 4 heads
    with pytest.raises(UserError, match=r"head dims \(8, 16\), this model 4"):
        resolve_attention_kernel(cfg("kernel"), head_dim_4, torch.device("cpu"))
    mixed = TrainConfig(dataset="d", objective="ad", out="o", training_args={"bf16": True})
    assert resolve_attention_kernel(mixed, config, torch.device("cpu")) == "torch"
    eager = grid_config("ad", attn_implementation="eager")  # the caller's choice stays
    assert resolve_attention_kernel(cfg("auto"), eager, torch.device("cpu")) == "torch"
    with pytest.raises(UserError, match="asks for attn_implementation='eager'"):
        resolve_attention_kernel(cfg("kernel"), eager, torch.device("cpu"))
