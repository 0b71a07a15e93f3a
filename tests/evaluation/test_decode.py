"""The lean decoder (``decode.py``) against HF's ``LlamaModel`` forward, and its KV window store."""

from __future__ import annotations

import pytest
import torch

from lhf_hf.evaluation.context import Context
from lhf_hf.evaluation.decode import LeanLlama, WindowKV, supported
from lhf_hf.modeling import ICRLModel, icrl_config


def _model(layers: int = 3, kv_heads: int | None = None, **extra) -> ICRLModel:
    kw = {"num_key_value_heads": kv_heads} if kv_heads else {}
    cfg = icrl_config(
        "tiny",
        objective="dicp",
        context_length=4,
        state_bins=9,
        num_hidden_layers=layers,
        **kw,
        **extra,
    )
    torch.manual_seed(1)
    return ICRLModel(cfg).eval()


def test_window_kv_keeps_the_live_span_through_evictions_compactions_and_growth():
    # appends of 1-2 tokens, 2 evicted every third step: the live span outgrows the capacity
    g = torch.Generator().manual_seed(0)
    k0 = torch.randn(2, 3, 2, 4, generator=g)
    kv = WindowKV(k0, -k0, capacity=6)
    ref = [k0]
    for step in range(40):
        n = 1 + step % 2
        k = torch.randn(2, 3, n, 4, generator=g)
        kv.append(k, -k)
        ref.append(k)
        want = torch.cat(ref, dim=2)
        if step % 3 == 0:  # drop the oldest tokens sometimes
            kv.evict(2)
        live = len(kv)
        torch.testing.assert_close(kv.keys, want[:, :, want.shape[2] - live :], rtol=0, atol=0)
        torch.testing.assert_close(kv.values, -kv.keys, rtol=0, atol=0)
    # growth: never evicting keeps every token
    kv = WindowKV(k0, k0, capacity=4)
    for _ in range(10):
        kv.append(k0, k0)
    assert len(kv) == 22 and kv.cap >= 22
    torch.testing.assert_close(kv.keys, k0.repeat(1, 1, 11, 1), rtol=0, atol=0)


@torch.no_grad()
@pytest.mark.parametrize("kv_heads", [None, 2])  # multi-head and grouped-query attention
def test_lean_decoder_equals_the_hf_forward_with_a_cache(kv_heads):
    """Appending 1 token, then 2 at once (causal and with a custom additive mask), the hidden states
    and the keys/values equal ``LlamaModel``'s with a ``DynamicCache``, 3 layers deep."""
    model = _model(kv_heads=kv_heads)
    lean = LeanLlama(model)
    D = model.config.hidden_size
    g = torch.Generator().manual_seed(2)
    hf_cache, lean_cache, pos = None, None, 0
    for n, masked in [(3, False), (1, False), (2, False), (2, True), (1, False)]:
        x = torch.randn(2, n, D, generator=g)
        ids = torch.arange(pos, pos + n)[None].expand(2, n)
        mask = None
        if masked:  # the second new token may not see the oldest cached one
            mask = torch.zeros(2, 1, n, pos + n)
            mask[:, :, 1, 0] = float("-inf")
            mask[:, :, 0, pos + 1] = float("-inf")
        want, hf_cache = model.run_backbone(
            x,
            backbone_cache=hf_cache,
            position_ids=ids,
            use_cache=True,
            attention_mask=mask,
        )
        got, lean_cache = lean(x, ids, lean_cache, mask)
        torch.testing.assert_close(got, want, atol=2e-6, rtol=1e-5)
        for layer, kv in zip(hf_cache.layers, lean_cache, strict=True):
            torch.testing.assert_close(kv.values, layer.values, atol=1e-6, rtol=1e-5)
            # the lean keys are RoPE'd keys too (queries carry the attention scale instead)
            torch.testing.assert_close(kv.keys, layer.keys, atol=1e-6, rtol=1e-5)
        pos += n


def test_unsupported_models_fall_back_or_fail_clearly():
    model = _model()
    assert supported(model) is None
    model.train()
    assert "training" in supported(model)
    assert Context(model, mode="cache").engine == "hf"  # auto falls back
    with pytest.raises(ValueError, match="engine='lean' cannot run this model: .*training"):
        Context(model, mode="cache", engine="lean")
    with pytest.raises(ValueError, match="unknown context engine 'fast'"):
        Context(model.eval(), engine="fast")
    with pytest.raises(ValueError, match="does not support this model: hidden_act 'gelu'"):
        LeanLlama(_model(hidden_act="gelu"))
    # the numpy decoder computes in float32: other dtypes run HF's forward
    assert "dtype torch.float64" in supported(_model().double())
    assert Context(_model().double(), mode="cache").engine == "hf"
    # the recompute and window modes run HF's forward, with auto its attention in the C++ kernel
    # where it loads (test_context.py: the same function)
    from lhf_hf.modeling import attention_kernel

    kernel = "kernel" if attention_kernel.available() is None else "hf"
    assert Context(model.eval(), mode="recompute").engine == kernel
    assert Context(model.eval(), mode="window", engine="hf").engine == "hf"
