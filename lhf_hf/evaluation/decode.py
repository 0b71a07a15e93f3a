"""A lean, exact re-statement of ``LlamaModel.forward`` for the evaluation context's cached steps.

Why: at the paper's model sizes (hidden 32, 4 layers) a cached rollout step computes almost nothing
(1-2 new tokens x 8 tasks), and ``LlamaModel.forward`` spends ~0.7 ms per decoder layer in module
calls, hooks, ``DynamicCache`` concatenations and wrappers (profiled: ~58 module calls, ~3 ms per
step).  This class runs the same arithmetic from the same ``LlamaModel``'s weights with ~20 tensor
ops per layer:

- RMSNorm's formula (the mean as a sum times 1/D, exact for power-of-two widths) with its weight
  folded into the next matmul, ``W diag(w)``;
- one matmul for queries, keys, values *and* their RoPE partners: ``rotate_half(W x)`` equals
  ``(P W) x`` for the signed permutation ``P`` of ``rotate_half``, so the rows ``P W_q, P W_k`` are
  appended to the fused weight and RoPE becomes ``q * cos + q' * sin`` (HF's formula, with cos/sin
  from the model's own ``rotary_emb``, tabulated by position); the attention scale is folded into
  the query rows;
- keys and values in a preallocated window buffer per layer (``WindowKV``): a new token is written
  in place and evicted tokens are dropped by moving a start index, instead of a ``torch.cat`` per
  layer per step;
- attention written out (``softmax(q k^T + mask) v``, HF's eager formula) as two ``bmm`` that read
  the buffers in place (measured ~40 us per layer at one query token vs ~50 us for the SDPA kernel
  alone); residual adds fused into ``addmm``.

Folding weights and scales changes where products are rounded, so results equal HF's forward to
float rounding, not bit for bit (tests: hidden states, keys and values vs HF at 3-4 layers with the
DICP band masks, and identical rollout actions).  Only what the ICRL configs use is supported
(``supported`` says why not otherwise; the context then uses the HF forward): SiLU MLP without
biases, no attention bias, default RoPE, eval mode.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from transformers import LlamaModel


def supported(model) -> str | None:
    """``None`` when ``model``'s backbone can run here, else the reason it cannot."""
    if not isinstance(getattr(model, "backbone", None), LlamaModel):
        return "the model has no LlamaModel backbone"
    c = model.backbone.config
    rope = (getattr(c, "rope_parameters", None) or {}).get("rope_type", "default")
    checks = [
        (model.training, "the model is in training mode (dropout)"),
        (c.hidden_act != "silu", f"hidden_act {c.hidden_act!r} (only silu)"),
        (bool(getattr(c, "attention_bias", False)), "attention biases"),
        (bool(getattr(c, "mlp_bias", False)), "MLP biases"),
        (rope != "default", f"rope_type {rope!r} (only default)"),
        (getattr(c, "pretraining_tp", 1) != 1, "pretraining_tp != 1"),
    ]
    for failed, why in checks:
        if failed:
            return why
    return None


class WindowKV:
    """Keys and values of one layer for a sliding window: a (B, Hkv, capacity, Dh) buffer each and
    the span ``[start, end)`` in use.  Appending writes in place; when the buffer's end is reached
    the live span is moved to the front (one copy per ~capacity/2 appends)."""

    def __init__(self, k: torch.Tensor, v: torch.Tensor, capacity: int) -> None:
        B, H, n, Dh = k.shape
        self.cap = max(capacity, 2 * n)
        self.k = torch.empty(B, H, self.cap, Dh, dtype=k.dtype)
        self.v = torch.empty_like(self.k)
        self.start, self.end = 0, 0
        self.append(k, v)

    def append(self, k: torch.Tensor, v: torch.Tensor) -> None:
        n = k.shape[2]
        if self.end + n > self.cap:
            live = self.end - self.start
            if live + n > self.cap:  # more tokens kept than planned for: grow
                self.cap = 2 * (live + n)
                k_new = torch.empty(
                    *self.k.shape[:2], self.cap, self.k.shape[3], dtype=self.k.dtype
                )
                v_new = torch.empty_like(k_new)
            else:
                k_new, v_new = self.k, self.v
            # cloned first: compacting in place, the live span and its new place may overlap
            k_new[:, :, :live] = self.k[:, :, self.start : self.end].clone()
            v_new[:, :, :live] = self.v[:, :, self.start : self.end].clone()
            self.k, self.v, self.start, self.end = k_new, v_new, 0, live
        self.k[:, :, self.end : self.end + n] = k
        self.v[:, :, self.end : self.end + n] = v
        self.end += n

    def evict(self, drop: int) -> None:
        self.start = min(self.start + drop, self.end)

    @property
    def keys(self) -> torch.Tensor:
        return self.k[:, :, self.start : self.end]  # (B, Hkv, live, Dh) view

    @property
    def values(self) -> torch.Tensor:
        return self.v[:, :, self.start : self.end]

    @property
    def flat_keys(self) -> torch.Tensor:
        B, H, cap, Dh = self.k.shape
        return self.k.view(B * H, cap, Dh)[:, self.start : self.end]  # (B H, live, Dh) view

    @property
    def flat_values(self) -> torch.Tensor:
        B, H, cap, Dh = self.v.shape
        return self.v.view(B * H, cap, Dh)[:, self.start : self.end]

    def __len__(self) -> int:
        return self.end - self.start


class LeanLlama:
    """``LlamaModel`` over new token embeddings with a window KV cache, in few fused tensor ops.

    The weights are copied (fused) once, at construction: build it for a frozen model.
    ``capacity``: tokens the KV buffers hold before compacting (the window plus room to append).
    """

    def __init__(self, model, capacity: int = 512) -> None:
        why = supported(model)
        if why is not None:
            raise ValueError(f"the lean decoder does not support this model: {why}")
        bb = model.backbone
        c = bb.config
        self.heads, self.kv_heads = c.num_attention_heads, c.num_key_value_heads
        self.head_dim = getattr(c, "head_dim", None) or c.hidden_size // c.num_attention_heads
        self.eps = c.rms_norm_eps
        self.scale = self.head_dim**-0.5
        self.capacity = capacity
        self.rotary = bb.rotary_emb
        self.norm_w = bb.norm.weight.detach()
        self.cos = self.sin = torch.zeros(0, self.head_dim)
        Dh, half = self.head_dim, self.head_dim // 2

        def rotate_rows(w: torch.Tensor, heads: int) -> torch.Tensor:
            # rows of rotate_half(W x) = (P W) x: per head, [-w[half:], w[:half]]
            w = w.view(heads, Dh, -1)  # (heads, Dh, D)
            return torch.cat([-w[:, half:], w[:, :half]], dim=1).reshape(heads * Dh, -1)

        self.layers = []
        with torch.no_grad():
            for layer in bb.layers:
                a, m = layer.self_attn, layer.mlp
                H, Hkv = self.heads, self.kv_heads
                # RMSNorm's weight is folded into the next matmul (W diag(w)) and the attention
                # scale into the query rows: the same products, rounded once differently.
                w_in = layer.input_layernorm.weight.detach()
                w_q = a.q_proj.weight * self.scale
                w_qkv = (
                    torch.cat(
                        [
                            w_q,
                            a.k_proj.weight,
                            a.v_proj.weight,
                            rotate_rows(w_q, H),
                            rotate_rows(a.k_proj.weight, Hkv),
                        ]
                    )
                    * w_in
                )  # ((2 H + 3 Hkv) Dh, D)
                w_post = layer.post_attention_layernorm.weight.detach()
                self.layers.append(
                    (
                        w_qkv,
                        a.o_proj.weight.detach().t().contiguous(),  # (H Dh, D) for addmm
                        torch.cat([m.gate_proj.weight, m.up_proj.weight]) * w_post,  # (2 I, D)
                        m.down_proj.weight.detach().t().contiguous(),  # (I, D) for addmm
                    )
                )

    def _rms(self, x: torch.Tensor) -> torch.Tensor:
        """LlamaRMSNorm without its weight (folded into the next matmul).  The mean as a sum times
        1/D: bit-identical for the power-of-two widths of the presets, and ~4x cheaper than ``mean``
        on these tiny tensors."""
        return x * (x.pow(2).sum(-1, keepdim=True).mul_(1.0 / x.shape[-1]).add_(self.eps)).rsqrt_()

    def _rope_table(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """cos, sin (B, n, 1, Dh) for ``positions`` (B, n), from the model's ``rotary_emb``."""
        top = int(positions.max()) + 1
        if top > len(self.cos):
            size = max(top, 2 * len(self.cos), 1024)
            pos = torch.arange(size)[None]  # (1, size)
            # rotary_emb reads only the dtype and device of its first argument
            cos, sin = self.rotary(self.norm_w[None, None], pos)  # (1, size, Dh)
            self.cos, self.sin = cos[0], sin[0]
        return self.cos[positions].unsqueeze(2), self.sin[positions].unsqueeze(2)

    def _attend(self, q: torch.Tensor, kv: WindowKV, mask: torch.Tensor | None) -> torch.Tensor:
        """softmax(q k^T + mask) v; q (B, H, n, Dh) pre-scaled -> (B, H, n, Dh)."""
        B, H, n, Dh = q.shape
        if self.kv_heads == H:
            # (B H, live, Dh) views of the buffers: bmm reads them in place (matmul on the 4-d
            # window views would copy them first)
            keys, values = kv.flat_keys, kv.flat_values
            scores = torch.bmm(q.reshape(B * H, n, Dh), keys.transpose(1, 2))  # (B H, n, live)
            if mask is not None:
                scores = (scores.view(B, H, n, -1) + mask).view(B * H, n, -1)
            return torch.bmm(torch.softmax(scores, dim=-1), values).view(B, H, n, Dh)
        rep = H // self.kv_heads  # grouped-query attention: each key head serves `rep` query heads
        keys = kv.keys.repeat_interleave(rep, dim=1)  # (B, H, live, Dh)
        values = kv.values.repeat_interleave(rep, dim=1)
        scores = torch.matmul(q, keys.transpose(2, 3))  # (B, H, n, live)
        if mask is not None:
            scores = scores + mask
        return torch.matmul(torch.softmax(scores, dim=-1), values)

    @torch.no_grad()
    def __call__(
        self,
        embeds: torch.Tensor,
        position_ids: torch.Tensor,
        cache: list[WindowKV] | None,
        attention_mask: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, list[WindowKV]]:
        """embeds (B, n, D), position_ids (B, n), cache (None or one ``WindowKV`` per layer),
        attention_mask None (causal) or additive (B, 1, n, past + n) -> (hidden (B, n, D), cache)."""
        B, n, D = embeds.shape
        H, Hkv, Dh = self.heads, self.kv_heads, self.head_dim
        past = len(cache[0]) if cache else 0
        if attention_mask is None and n > 1:  # causal over the new tokens, all of the past visible
            keep = torch.ones(n, past + n, dtype=torch.bool).tril(past)
            attention_mask = torch.zeros(n, past + n).masked_fill_(~keep, float("-inf"))
        cos, sin = self._rope_table(position_ids)  # (B, n, 1, Dh)
        new_cache = [] if not cache else cache
        x = embeds.reshape(B * n, D)  # (B n, D)
        for i, (w_qkv, w_o, w_gu, w_down) in enumerate(self.layers):
            proj = F.linear(self._rms(x), w_qkv).view(B, n, -1)  # (B, n, (2H + 3Hkv) Dh)
            qk, v, qk_rot = proj.split([(H + Hkv) * Dh, Hkv * Dh, (H + Hkv) * Dh], dim=-1)
            # RoPE on queries and keys at once: x * cos + rotate_half(x) * sin
            qk = torch.addcmul(
                qk.view(B, n, H + Hkv, Dh) * cos, qk_rot.view(B, n, H + Hkv, Dh), sin
            )  # (B, n, H + Hkv, Dh)
            q = qk[:, :, :H].transpose(1, 2)  # (B, H, n, Dh), pre-scaled by Dh^-0.5
            k = qk[:, :, H:].transpose(1, 2)  # (B, Hkv, n, Dh)
            v = v.view(B, n, Hkv, Dh).transpose(1, 2)  # (B, Hkv, n, Dh)
            if cache:
                cache[i].append(k, v)
            else:
                new_cache.append(WindowKV(k, v, self.capacity))
            attn = self._attend(q, new_cache[i], attention_mask)  # (B, H, n, Dh)
            x = torch.addmm(x, attn.transpose(1, 2).reshape(B * n, H * Dh), w_o)  # (B n, D)
            gate, up = F.linear(self._rms(x), w_gu).chunk(2, dim=-1)  # (B n, I) each
            x = torch.addmm(x, F.silu(gate).mul_(up), w_down)  # (B n, D)
        x = x.view(B, n, D)
        return self.norm_w * self._rms(x), new_cache
