"""The backbone's attention function: PyTorch SDPA, except attention with dropout (training), which is
computed here with a cheaper dropout mask.

Why (BENCHMARKS.md, "Training throughput"): on CPU, SDPA with ``dropout_p > 0`` runs its math path,
which draws the dropout mask with ``bernoulli_`` (one Mersenne-Twister draw per attention weight:
about 10 ms per layer for 64 x 4 heads x 80 x 80 weights on 2 cores, 30 % of a paper-preset AD
training step) and wraps the softmax in a "safe softmax" (``isneginf`` / ``all`` / ``where`` passes,
another 8 %).  Here the mask costs one draw per *four* weights: 64 random bits per draw, read as four
16-bit integers, each compared with a threshold.  Everything else is the math SDPA does:

    P = softmax(Q K^T * scale + mask);  out = (P * keep) V,  keep = 0 or 1 / (1 - p)

The drop probability is rounded to a multiple of 2^-16 (0.1 -> 6554 / 65536 = 0.100006) and the
kept weights are scaled by that rounded probability, so the expectation is exact (in float32; with
bfloat16 inputs the scale is rounded to bfloat16).  A row whose keys are all masked gives 0, as SDPA.

Everything else is ``sdpa_attention_forward`` itself, the same numbers as
``attn_implementation="sdpa"``: no dropout (evaluation, ``model.eval()``, ``attention_dropout=0``), a
drop probability outside [2^-17, 1), another device, autocast, a mask that takes gradients,
``softcap`` or ``position_bias``, and causal attention over a cache with more keys than queries
(SDPA's own alignment rules apply there; training never builds one).

The mask comes from torch's default CPU generator (``Tensor.random_``), which the training seed
(``TrainConfig.seed`` -> ``transformers.set_seed``) seeds: runs stay reproducible.
"""

from __future__ import annotations

import math

import torch
from transformers import AttentionInterface
from transformers.integrations.sdpa_attention import repeat_kv, sdpa_attention_forward
from transformers.masking_utils import ALL_MASK_ATTENTION_FUNCTIONS, sdpa_mask

NAME = "lhf_sdpa"  # the ``attn_implementation`` ICRLModel uses by default (modeling_icrl.py)
_LEVELS = 1 << 16  # a 16-bit draw per attention weight


def keep_weights(shape: tuple[int, ...], p: float) -> tuple[torch.Tensor, float]:
    """(float tensor of ``shape``: 0 where a weight is dropped, ``1 / (1 - p')`` where it is kept;
    ``p'``, the drop probability it was drawn with).

    Each element compares 16 random bits with ``round(p * 2^16)``, so ``p'`` is ``p`` rounded to a
    multiple of 2^-16, and the kept weights' scale ``1 / (1 - p')`` keeps the expectation exact."""
    n = math.prod(shape)
    words = torch.empty((n + 3) // 4, dtype=torch.int64).random_(-(2**63), None)  # 64 random bits
    # 4 int16 draws per word, each uniform in [-2^15, 2^15)
    bits = words.view(torch.int16)[:n].view(shape)
    level = round(p * _LEVELS)
    p_drawn = level / _LEVELS
    keep = (bits >= level - _LEVELS // 2).to(torch.float32)
    return keep.mul_(1.0 / (1.0 - p_drawn)), p_drawn


class DropoutAttention(torch.autograd.Function):
    """out = (softmax(q k^T + bias) * keep) v, with the backward written out.

    q (B, H, Lq, d) already scaled; k, v (B, H, Lk, d); bias: additive float mask broadcast to
    (B, H, Lq, Lk) (-inf = may not attend); keep (B, H, Lq, Lk) from ``keep_weights``;
    may_mask_rows: whether the bias can mask a whole row (then such rows give 0, as SDPA).

    Why not autograd: its graph of the same ops allocates and streams eight (Lq, Lk) tensors per
    layer and step (two of them clones made by out-of-place ``masked_fill``, itself slow on CPU);
    this one four, with multiplies only.  The softmax gradient's row term uses FlashAttention's
    identity sum_k dP_ik P_ik = dO_i . O_i, a product over (Lq, d) instead of (Lq, Lk)."""

    @staticmethod
    def forward(ctx, q, k, v, bias, keep, may_mask_rows: bool = True):
        scores = torch.matmul(q, k.transpose(-1, -2)).add_(bias)  # (B, H, Lq, Lk)
        probs = torch.softmax(scores, dim=-1)  # (B, H, Lq, Lk)
        del scores
        if may_mask_rows:
            # a row with every key masked is NaN after the softmax; SDPA gives it 0 (and 0 gradients)
            probs = probs.nan_to_num_(0.0)
        kept = probs * keep  # (B, H, Lq, Lk)
        out = torch.matmul(kept, v)  # (B, H, Lq, d)
        ctx.save_for_backward(q, k, v, probs, kept, keep, out)
        return out

    @staticmethod
    def backward(ctx, grad_out):
        q, k, v, probs, kept, keep, out = ctx.saved_tensors
        grad_out = grad_out.contiguous()  # (B, H, Lq, d)
        row = (grad_out * out).sum(-1, keepdim=True)  # (B, H, Lq, 1): sum_k dP_ik P_ik
        # dP = (dO v^T) * keep; dS = P * (dP - row)
        grad_s = torch.matmul(grad_out, v.transpose(-1, -2))  # (B, H, Lq, Lk)
        grad_s.mul_(keep).sub_(row).mul_(probs)
        grad_q = torch.matmul(grad_s, k)  # (B, H, Lq, d)
        grad_k = torch.matmul(grad_s.transpose(-1, -2), q)  # (B, H, Lk, d)
        grad_v = torch.matmul(kept.transpose(-1, -2), grad_out)  # (B, H, Lk, d)
        return grad_q, grad_k, grad_v, None, None, None


def outside_cpu_paths(query, attention_mask, kwargs) -> bool:
    """The cases no CPU training path here takes (this module's and the C++ kernel's): another
    device, autocast, a mask that takes gradients, ``position_bias`` or ``softcap``."""
    return (
        query.device.type != "cpu"
        or torch.is_autocast_enabled("cpu")
        or (attention_mask is not None and attention_mask.requires_grad)
        or kwargs.get("position_bias") is not None
        or kwargs.get("softcap") is not None
    )


def _sdpa_does_it(query, attention_mask, dropout: float, kwargs) -> bool:
    """The cases this module leaves to ``sdpa_attention_forward`` (module docstring)."""
    return (
        not 1 <= round(dropout * _LEVELS) < _LEVELS  # p < 2^-17 rounds to 0; p near 1
        or outside_cpu_paths(query, attention_mask, kwargs)
    )


def attention_forward(
    module: torch.nn.Module,
    query: torch.Tensor,
    key: torch.Tensor,
    value: torch.Tensor,
    attention_mask: torch.Tensor | None,
    dropout: float = 0.0,
    scaling: float | None = None,
    **kwargs,
) -> tuple[torch.Tensor, None]:
    """``transformers`` attention interface: query (B, H, Lq, d), key/value (B, Hkv, Lk, d) ->
    ((B, Lq, H, d), None).  attention_mask: None (causal unless ``is_causal`` / ``module.is_causal``
    is False, as SDPA reads it), bool (True = may attend) or an additive float bias, broadcast to
    (B, H, Lq, Lk)."""
    B, H, Lq, d = query.shape
    Lk = key.shape[2]
    is_causal = kwargs.get("is_causal")
    is_causal = getattr(module, "is_causal", True) if is_causal is None else is_causal
    # SDPA's rule: a None mask is causal for more than one query (a single query sees every key)
    is_causal = bool(is_causal) and attention_mask is None and Lq > 1
    if _sdpa_does_it(query, attention_mask, dropout, kwargs) or (is_causal and Lk != Lq):
        return sdpa_attention_forward(
            module, query, key, value, attention_mask, dropout=dropout, scaling=scaling, **kwargs
        )
    groups = getattr(module, "num_key_value_groups", 1)
    key, value = repeat_kv(key, groups), repeat_kv(value, groups)  # (B, H, Lk, d)
    scale = d**-0.5 if scaling is None else scaling
    if attention_mask is None:
        bias = torch.zeros(Lq, Lk, dtype=query.dtype)
        if is_causal:  # query i sees keys 0 .. i (Lq == Lk here)
            bias.fill_(float("-inf")).triu_(1)
    elif attention_mask.dtype == torch.bool:
        bias = torch.zeros(attention_mask.shape, dtype=query.dtype)
        bias.masked_fill_(~attention_mask, float("-inf"))
    else:
        bias = attention_mask.to(query.dtype)
    keep, _ = keep_weights((B, H, Lq, Lk), dropout)
    out = DropoutAttention.apply(
        query * scale, key, value, bias, keep.to(query.dtype), attention_mask is not None
    )
    return out.transpose(1, 2).contiguous(), None  # (B, H, Lq, d) -> (B, Lq, H, d)


AttentionInterface.register(NAME, attention_forward)
# the masks SDPA gets (None for plain causal attention, which attention_forward builds itself)
ALL_MASK_ATTENTION_FUNCTIONS.register(NAME, sdpa_mask)
