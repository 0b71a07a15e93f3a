"""Training attention (``lhf_sdpa``): SDPA's numbers without dropout, the eager formula with it
(forward and hand-written backward against autograd), and a dropout mask with the asked rate."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from transformers import LlamaConfig, LlamaModel

from lhf_hf.modeling import ICRLModel, icrl_config, train_attention
from lhf_hf.modeling.train_attention import (
    DropoutAttention,
    attention_forward,
    keep_weights,
    sdpa_attention_forward,
)

from .test_modeling_icrl import grid_config, make_batch


def reference(q, k, v, bias, keep):
    """The eager formula through autograd: (softmax(q k^T + bias) * keep) v."""
    probs = torch.softmax(q @ k.transpose(-1, -2) + bias, dim=-1)
    return (probs * keep) @ v


def qkv(B=2, H=3, Lq=5, Lk=7, d=4, dtype=torch.float64, seed=0):
    g = torch.Generator().manual_seed(seed)
    return [
        torch.randn(B, H, L, d, generator=g, dtype=dtype, requires_grad=True) for L in (Lq, Lk, Lk)
    ]


def causal_bias(Lq, Lk, dtype=torch.float64):
    return torch.full((Lq, Lk), float("-inf"), dtype=dtype).triu_(Lk - Lq + 1)


@pytest.mark.slow
@pytest.mark.parametrize("Lq, Lk", [(6, 6), (3, 7)])
def test_forward_and_backward_match_autograd_of_the_formula(Lq, Lk):
    q, k, v = qkv(Lq=Lq, Lk=Lk)
    bias = causal_bias(Lq, Lk)
    keep, _ = keep_weights((2, 3, Lq, Lk), 0.3)
    keep = keep.double()
    assert (keep == 0).any() and (keep > 0).any()
    ours = DropoutAttention.apply(q, k, v, bias, keep)
    ref = reference(q, k, v, bias, keep)
    torch.testing.assert_close(ours, ref)
    g = torch.randn_like(ours)
    grads = torch.autograd.grad(ours, (q, k, v), g)
    ref_grads = torch.autograd.grad(ref, (q, k, v), g)
    for a, b in zip(grads, ref_grads, strict=True):
        torch.testing.assert_close(a, b)
    small = [x[:1, :1].detach().requires_grad_() for x in (q, k, v)]  # gradcheck: few inputs
    assert torch.autograd.gradcheck(
        lambda q, k, v: DropoutAttention.apply(q, k, v, bias, keep[:1, :1]), small
    )


class _Module(torch.nn.Module):
    def __init__(self, groups=1, causal=True):
        super().__init__()
        self.num_key_value_groups, self.is_causal = groups, causal


def test_without_dropout_it_is_sdpa():
    q, k, v = qkv(dtype=torch.float32, Lq=6, Lk=6)
    out, _ = attention_forward(_Module(), q, k, v, None, dropout=0.0, scaling=0.5)
    ref = F.scaled_dot_product_attention(q, k, v, is_causal=True, scale=0.5).transpose(1, 2)
    assert torch.equal(out, ref)


@pytest.mark.parametrize("mask_kind", ["causal", "bool", "float"])
def test_with_dropout_it_is_the_eager_formula_with_its_mask(mask_kind):
    """Same seed -> the same keep weights inside attention_forward and here."""
    Lq = Lk = 6
    q, k, v = qkv(dtype=torch.float32, Lq=Lq, Lk=Lk)
    allowed = torch.rand(2, 1, Lq, Lk, generator=torch.Generator().manual_seed(3)) < 0.7
    allowed |= torch.eye(Lq, dtype=torch.bool)  # every query sees a key
    mask = {"causal": None, "bool": allowed, "float": None}[mask_kind]
    if mask_kind == "float":
        mask = torch.zeros(allowed.shape).masked_fill_(~allowed, float("-inf"))
    bias = (
        causal_bias(Lq, Lk, torch.float32)
        if mask_kind == "causal"
        else (torch.zeros(allowed.shape).masked_fill_(~allowed, float("-inf")))
    )
    torch.manual_seed(11)
    out, _ = attention_forward(_Module(), q, k, v, mask, dropout=0.25, scaling=0.3)
    torch.manual_seed(11)
    keep, _ = keep_weights((2, 3, Lq, Lk), 0.25)
    ref = reference(q * 0.3, k, v, bias, keep).transpose(1, 2)
    torch.testing.assert_close(out, ref)


def test_keep_weights_rate_values_and_seed():
    torch.manual_seed(0)
    keep, p = keep_weights((64, 4, 80, 80), 0.1)
    assert p == 6554 / 65536  # 0.1 rounded to a multiple of 2^-16
    assert keep.unique().tolist() == [0.0, pytest.approx(1 / (1 - p))]
    n = keep.numel()
    dropped = (keep == 0).double().mean().item()
    # binomial standard error sqrt(p (1 - p) / n) = 2.4e-4; 6 of them
    assert abs(dropped - p) < 6 * (p * (1 - p) / n) ** 0.5
    assert abs(keep.double().mean().item() - 1.0) < 2e-3  # unbiased in expectation
    # every one of the four 16-bit draws in a 64-bit word has the same rate
    lanes = (keep == 0).flatten()[: n - n % 4].view(-1, 4).double().mean(0)
    assert (lanes - p).abs().max() < 6 * (p * (1 - p) / (n / 4)) ** 0.5
    torch.manual_seed(0)
    again, _ = keep_weights((64, 4, 80, 80), 0.1)
    assert torch.equal(keep, again)
    assert keep_weights((10,), 0.0)[0].eq(1).all()


def test_model_uses_it_by_default_and_matches_sdpa_without_dropout():
    torch.manual_seed(0)
    ours = ICRLModel(grid_config("ad"))
    assert ours.config._attn_implementation == train_attention.NAME
    torch.manual_seed(0)
    sdpa = ICRLModel(grid_config("ad", attn_implementation="sdpa"))
    assert sdpa.config._attn_implementation == "sdpa"
    batch, actions = make_batch(ours.config)
    for m in (ours, sdpa):
        m.eval()  # no dropout: both are SDPA
    torch.testing.assert_close(
        ours(**batch).action_logits, sdpa(**batch).action_logits, rtol=0, atol=0
    )


@pytest.mark.slow
@pytest.mark.parametrize("objective", ["ad", "dicp"])
def test_training_forward_matches_eager_llama_math(objective, monkeypatch):
    """Training mode with dropout: the model's loss and gradients equal the ones of the same model
    whose attention is transformers' eager attention with our keep weights (patched in)."""
    cfg = grid_config(objective, attention_dropout=0.2, embedding_dropout=0.0)
    torch.manual_seed(0)
    ours = ICRLModel(cfg).train()
    torch.manual_seed(0)
    eager = ICRLModel(
        grid_config(
            objective, attention_dropout=0.2, embedding_dropout=0.0, attn_implementation="eager"
        )
    ).train()
    batch, actions = make_batch(cfg)
    batch["action_labels"] = actions
    torch.manual_seed(5)
    loss = ours(**batch).loss
    loss.backward()

    # eager attention draws its mask with F.dropout: give it ours instead, drawn from the same seed
    import transformers.models.llama.modeling_llama as llama

    def dropout_with_our_mask(x, p=0.5, training=True, inplace=False):
        if p == 0 or not training:
            return x
        keep, _ = keep_weights(tuple(x.shape), p)
        return x * keep

    monkeypatch.setattr(llama.nn.functional, "dropout", dropout_with_our_mask)
    torch.manual_seed(5)
    ref = eager(**batch).loss
    ref.backward()
    torch.testing.assert_close(loss, ref)
    for (name, a), b in zip(ours.named_parameters(), eager.parameters(), strict=True):
        if a.grad is not None:
            torch.testing.assert_close(a.grad, b.grad, msg=name)


def test_plain_llama_backbone_is_unchanged():
    """Registering the function changes nothing for other models."""
    m = LlamaModel(
        LlamaConfig(
            hidden_size=16,
            intermediate_size=32,
            num_hidden_layers=1,
            num_attention_heads=2,
            vocab_size=10,
        )
    )
    assert m.config._attn_implementation == "sdpa"


def test_paper_config_trains_with_it():
    m = ICRLModel(icrl_config("paper", objective="ad", state_dim=2, state_bins=9, action_dim=5))
    assert m.config._attn_implementation == train_attention.NAME


def test_a_loaded_checkpoint_trains_with_it_too(tmp_path):
    ICRLModel(grid_config("ad")).save_pretrained(tmp_path)
    assert ICRLModel.from_pretrained(tmp_path).config._attn_implementation == train_attention.NAME


def test_grouped_query_heads_non_causal_and_default_scaling():
    """Two query heads per key/value head; ``is_causal=False`` with no mask: every key is seen;
    no ``scaling``: 1 / sqrt(d)."""
    g = torch.Generator().manual_seed(1)
    q = torch.randn(2, 4, 5, 4, generator=g)
    k, v = torch.randn(2, 2, 5, 4, generator=g), torch.randn(2, 2, 5, 4, generator=g)
    torch.manual_seed(2)
    out, _ = attention_forward(_Module(groups=2), q, k, v, None, dropout=0.3, is_causal=False)
    torch.manual_seed(2)
    keep, _ = keep_weights((2, 4, 5, 5), 0.3)
    k2, v2 = k.repeat_interleave(2, dim=1), v.repeat_interleave(2, dim=1)
    ref = reference(q * 0.5, k2, v2, torch.zeros(5, 5), keep).transpose(1, 2)
    torch.testing.assert_close(out, ref)


def test_cases_left_to_sdpa_are_sdpa():
    """More keys than queries with no mask (a cache: SDPA's alignment), a drop probability that
    rounds to 0, a mask that takes gradients: the same numbers as SDPA under the same seed."""
    q, k, v = qkv(dtype=torch.float32, Lq=3, Lk=5)
    learned = torch.zeros(3, 5, requires_grad=True)
    for mask, p in ((None, 0.2), (None, 1e-6), (learned, 0.2)):
        torch.manual_seed(4)
        ours, _ = attention_forward(_Module(), q, k, v, mask, dropout=p)
        torch.manual_seed(4)
        ref, _ = sdpa_attention_forward(_Module(), q, k, v, mask, dropout=p)
        assert torch.equal(ours, ref)
    with pytest.raises(ValueError, match="softcap"):
        attention_forward(_Module(), q, k, v, None, dropout=0.2, softcap=30.0)


def test_a_row_with_every_key_masked_gives_zero_as_sdpa():
    q, k, v = qkv(dtype=torch.float32, Lq=4, Lk=4)
    allowed = torch.ones(1, 1, 4, 4, dtype=torch.bool)
    allowed[..., 1, :] = False
    out, _ = attention_forward(_Module(), q, k, v, allowed, dropout=0.2)
    assert torch.isfinite(out).all() and (out[:, 1] == 0).all()
    grads = torch.autograd.grad(out.sum(), (q, k, v))
    assert all(torch.isfinite(g).all() for g in grads)
    assert (grads[0][:, :, 1] == 0).all()


def test_the_four_lanes_of_a_draw_are_independent():
    """P(two lanes of one 64-bit word both dropped) = p^2 for every pair of lanes."""
    torch.manual_seed(1)
    keep, p = keep_weights((1 << 22,), 0.5)
    lanes = (keep == 0).view(-1, 4).double()  # (words, 4)
    n = lanes.shape[0]
    for a in range(4):
        for b in range(a + 1, 4):
            both = (lanes[:, a] * lanes[:, b]).mean().item()
            assert abs(both - p * p) < 6 * (p * p * (1 - p * p) / n) ** 0.5
