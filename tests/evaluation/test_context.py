"""The sliding context against its definition: sliding-window attention over the whole stream."""

from __future__ import annotations

import pytest
import torch

from lhf_hf.evaluation.context import Context
from lhf_hf.modeling import ICRLModel, icrl_config
from lhf_hf.modeling.attention import band_mask


def _model(objective: str, layers: int, context: int) -> ICRLModel:
    cfg = icrl_config(
        "tiny", objective=objective, context_length=context, state_bins=9, num_hidden_layers=layers
    )
    torch.manual_seed(0)
    return ICRLModel(cfg).eval()


@pytest.mark.slow
@torch.no_grad()
@pytest.mark.parametrize("engine", ["lean", "hf"])
@pytest.mark.parametrize("objective", ["ad", "dicp"])
def test_cache_and_recompute_equal_a_full_stream_banded_forward(objective, engine):
    """Definition: every token attends to the W tokens ending at itself (W = K, DICP: 2K - 1 for a
    transition token, 2K for a query-action token).  One forward over the whole stream with that
    band is the reference; the KV cache (evictions, DICP's two tokens per step) and the recompute
    over the receptive field must give the same hidden states for every new token, 4 layers deep."""
    K, layers = 5, 4
    model = _model(objective, layers, K)
    D = model.config.hidden_size
    g = torch.Generator().manual_seed(0)
    cache = Context(model, mode="cache", engine=engine)
    assert cache.engine == engine
    recompute, window = (Context(model, mode=m) for m in ("recompute", "window"))
    W = cache.max_tokens
    assert W == (2 * K - 1 if objective == "dicp" else K)
    stream, wins = [], []
    for step in range(6 * K):  # many evictions
        is_q = [True, False] if objective == "dicp" and step else [False]
        tok = torch.randn(2, len(is_q), D, generator=g)  # (B, n, D)
        got = cache.append(tok, is_q)
        got_r = recompute.append(tok, is_q)
        got_w = window.append(tok, is_q)
        stream.append(tok)
        wins += [W + int(q) for q in is_q]
        seq = torch.cat(stream, dim=1)  # (B, N, D)
        N = seq.shape[1]
        pos = torch.arange(N)
        mask = band_mask(pos, torch.tensor(wins), pos)[None, None].expand(2, 1, N, N)
        want, _ = model.run_backbone(
            seq, position_ids=pos[None].expand(2, N), use_cache=False, attention_mask=mask
        )
        want = want[:, -len(is_q) :]
        torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(got_r, want, atol=1e-5, rtol=1e-5)
        if N <= W:  # before the window first fills, the reference protocol is the same function
            torch.testing.assert_close(got_w[:, -1], want[:, -1], atol=1e-5, rtol=1e-5)
    # the cache keeps what the next tokens can see; the recompute keeps the receptive field
    w_max, n = (W + 1, 2) if objective == "dicp" else (W, 1)
    assert cache.length <= W + 2 and recompute.length == layers * (w_max - 1) + n


def test_unknown_mode():
    with pytest.raises(ValueError, match="unknown context mode 'fast'"):
        Context(_model("ad", 1, 4), mode="fast")


@torch.no_grad()
def test_window_snapshot_is_the_last_append_s_encoding_without_another_forward():
    """``window`` mode: a planner's snapshot hands over the keys and values the last ``append``
    computed (no second encoding of the window per planned step), equal to a fresh encoding of the
    window with positions from 0; extending the snapshot leaves the context's own cache alone."""
    model = _model("dicp", 2, 3)
    g = torch.Generator().manual_seed(0)
    D = model.config.hidden_size
    ctx = Context(model, mode="window")
    ctx.append(torch.randn(2, 1, D, generator=g))
    for _ in range(7):  # more than the window: the oldest tokens are dropped
        ctx.append(torch.randn(2, 2, D, generator=g), [True, False])
    calls = []
    run = model.run_backbone
    model.run_backbone = lambda *a, **k: calls.append(1) or run(*a, **k)
    cache, L, pos = ctx.snapshot()
    assert calls == [] and L == pos == ctx.embeds.shape[1] == ctx.max_tokens
    _, fresh = run(ctx.embeds, position_ids=torch.arange(L)[None].expand(2, L), use_cache=True)
    for got, want in zip(cache.layers, fresh.layers, strict=True):
        torch.testing.assert_close(got.keys, want.keys)
        torch.testing.assert_close(got.values, want.values)
    run(torch.randn(2, 3, D, generator=g), backbone_cache=cache, use_cache=True,
        position_ids=torch.arange(L, L + 3)[None].expand(2, 3))  # fmt: skip
    assert ctx.cache.layers[0].keys.shape[2] == L  # the context's cache did not grow


@torch.no_grad()
def test_window_contexts_through_the_attention_kernel_equal_the_models_own_attention():
    """``window`` (and ``recompute``) re-encode whole windows with HF's forward; with engine auto
    their attention runs in the C++ kernel (where it loads): the same hidden states and the same
    keys and values for a planner's snapshot as the model's own attention (engine hf)."""
    from lhf_hf.modeling import attention_kernel

    if attention_kernel.available() is not None:
        pytest.skip(f"no kernel: {attention_kernel.available()}")
    model = _model("dicp", 3, 4)
    g = torch.Generator().manual_seed(1)
    ctx = {e: Context(model, mode="window", engine=e) for e in ("auto", "hf")}
    assert ctx["auto"].engine == "kernel" and ctx["hf"].engine == "hf"
    for step in range(12):  # past the window (2K - 1 = 7 tokens)
        is_q = [True, False] if step else [False]
        tok = torch.randn(3, len(is_q), model.config.hidden_size, generator=g)
        got, want = (c.append(tok, is_q) for c in (ctx["auto"], ctx["hf"]))
        torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)
    snaps = [c.snapshot()[0] for c in (ctx["auto"], ctx["hf"])]
    for a, b in zip(snaps[0].layers, snaps[1].layers, strict=True):
        torch.testing.assert_close(a.keys, b.keys, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(a.values, b.values, atol=1e-5, rtol=1e-5)
    assert model.config._attn_implementation == "lhf_sdpa"  # the model's own, restored
