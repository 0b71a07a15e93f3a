"""A lean, exact re-statement of ``LlamaModel.forward`` for the evaluation context's cached steps.

Why: at the paper's model sizes (hidden 32, 4 layers) a cached rollout step computes almost nothing
(1-2 new tokens x 8 tasks), and ``LlamaModel.forward`` spends ~0.7 ms per decoder layer in module
calls, hooks, ``DynamicCache`` concatenations and wrappers (profiled: ~58 module calls, ~3 ms per
step).  This class runs the same arithmetic from the same ``LlamaModel``'s weights in ~25 array ops
per layer, in **numpy**: on arrays this small an op is pure dispatch overhead, ~1 us in numpy against
~3-4 us through torch's dispatcher (measured: a 4-layer paper-size AD step 0.37 ms in numpy vs
1.13 ms with the same ops in torch).  The arithmetic:

- RMSNorm's formula with its weight folded into the next matmul, ``W diag(w)``;
- one matmul for queries, keys, values *and* their RoPE partners: ``rotate_half(W x)`` equals
  ``(P W) x`` for the signed permutation ``P`` of ``rotate_half``, so the rows ``P W_q, P W_k`` are
  appended to the fused weight and RoPE becomes ``q * cos + q' * sin`` (HF's formula, with cos/sin
  from the model's own ``rotary_emb``, tabulated by position); the attention scale is folded into
  the query rows;
- keys and values in a preallocated window buffer per layer (``WindowKV``): a new token is written
  in place and evicted tokens are dropped by moving a start index, instead of a ``torch.cat`` per
  layer per step;
- attention written out (``softmax(q k^T + mask) v``, HF's eager formula) as two batched matmuls
  that read the buffers in place; SiLU as ``g * sigmoid(g)`` with ``sigmoid(g) = (1 + tanh(g/2))/2``
  (no overflow for large ``|g|``).

Folding weights and scales, and numpy's BLAS and transcendentals instead of torch's, change where
products are rounded, so results equal HF's forward to float32 rounding, not bit for bit (tests:
hidden states, keys and values vs HF at 3 layers with the DICP band masks, and identical rollout
actions).  Tensors cross the boundary without copies (``Tensor.numpy``, ``torch.from_numpy``).  Only
what the ICRL configs use is supported (``supported`` says why not otherwise; the context then uses
the HF forward): a float32 model on the CPU, SiLU MLP without biases, no attention bias, default
RoPE, eval mode.
"""

from __future__ import annotations

import numpy as np
import torch
from transformers import LlamaModel

from lhf_hf.errors import UserError


def supported(model) -> str | None:
    """``None`` when ``model``'s backbone can run here, else the reason it cannot."""
    if not isinstance(getattr(model, "backbone", None), LlamaModel):
        return "the model has no LlamaModel backbone"
    c = model.backbone.config
    rope = (getattr(c, "rope_parameters", None) or {}).get("rope_type", "default")
    p = next(model.backbone.parameters())
    checks = [
        (p.device.type != "cpu", f"the model is on {p.device} (the lean decoder runs on the CPU)"),
        (p.dtype != torch.float32, f"dtype {p.dtype} (only float32)"),
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
    """Keys and values of one layer for a sliding window: a (B, Hkv, capacity, Dh) float32 numpy
    buffer each and the span ``[start, end)`` in use.  Appending writes in place; when the buffer's
    end is reached the live span is moved to the front (one copy per ~capacity/2 appends).
    ``keys`` / ``values`` are torch views of the live span (no copy), e.g. for a planner's cache."""

    def __init__(self, k, v, capacity: int) -> None:
        k = np.asarray(k)
        B, H, n, Dh = k.shape
        self.cap = max(capacity, 2 * n)
        self.k = np.empty((B, H, self.cap, Dh), np.float32)
        self.v = np.empty_like(self.k)
        self.start, self.end = 0, 0
        self.append(k, v)

    def append(self, k, v) -> None:
        """k, v: (B, Hkv, n, Dh) arrays or CPU tensors."""
        n = k.shape[2]
        if self.end + n > self.cap:
            live = self.end - self.start
            if live + n > self.cap:  # more tokens kept than planned for: grow
                self.cap = 2 * (live + n)
                shape = (*self.k.shape[:2], self.cap, self.k.shape[3])
                k_new, v_new = np.empty(shape, np.float32), np.empty(shape, np.float32)
            else:
                k_new, v_new = self.k, self.v
            # copied first: compacting in place, the live span and its new place may overlap
            k_new[:, :, :live] = self.k[:, :, self.start : self.end].copy()
            v_new[:, :, :live] = self.v[:, :, self.start : self.end].copy()
            self.k, self.v, self.start, self.end = k_new, v_new, 0, live
        self.k[:, :, self.end : self.end + n] = k
        self.v[:, :, self.end : self.end + n] = v
        self.end += n

    def evict(self, drop: int) -> None:
        self.start = min(self.start + drop, self.end)

    @property
    def keys(self) -> torch.Tensor:
        return torch.from_numpy(self.k[:, :, self.start : self.end])  # (B, Hkv, live, Dh) view

    @property
    def values(self) -> torch.Tensor:
        return torch.from_numpy(self.v[:, :, self.start : self.end])

    def flat(self) -> tuple[np.ndarray, np.ndarray]:
        """(B Hkv, live, Dh) views of the keys and values (numpy)."""
        B, H, cap, Dh = self.k.shape
        sl = slice(self.start, self.end)
        return self.k.reshape(B * H, cap, Dh)[:, sl], self.v.reshape(B * H, cap, Dh)[:, sl]

    def __len__(self) -> int:
        return self.end - self.start


def _numpy(t: torch.Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


class LeanLlama:
    """``LlamaModel`` over new token embeddings with a window KV cache, in few fused numpy ops.

    The weights are copied (fused, transposed for ``x @ W``) once, at construction: build it for a
    frozen model.  ``capacity``: tokens the KV buffers hold before compacting (the window plus room
    to append).
    """

    def __init__(self, model, capacity: int = 512) -> None:
        why = supported(model)
        if why is not None:
            raise UserError(f"the lean decoder does not support this model: {why}")
        bb = model.backbone
        c = bb.config
        self.heads, self.kv_heads = c.num_attention_heads, c.num_key_value_heads
        self.head_dim = getattr(c, "head_dim", None) or c.hidden_size // c.num_attention_heads
        self.eps = np.float32(c.rms_norm_eps)
        self.scale = self.head_dim**-0.5
        self.capacity = capacity
        self.rotary = bb.rotary_emb
        self.norm_w = _numpy(bb.norm.weight)
        self.cos = self.sin = np.zeros((0, self.head_dim), np.float32)
        Dh, half = self.head_dim, self.head_dim // 2

        def rotate_rows(w: torch.Tensor, heads: int) -> torch.Tensor:
            # rows of rotate_half(W x) = (P W) x: per head, [-w[half:], w[:half]]
            w = w.view(heads, Dh, -1)  # (heads, Dh, D)
            return torch.cat([-w[:, half:], w[:, :half]], dim=1).reshape(heads * Dh, -1)

        def t(w: torch.Tensor) -> np.ndarray:  # (out, in) -> (in, out) for x @ W
            return np.ascontiguousarray(_numpy(w).T)

        self.layers = []
        with torch.no_grad():
            for layer in bb.layers:
                a, m = layer.self_attn, layer.mlp
                H, Hkv = self.heads, self.kv_heads
                # RMSNorm's weight is folded into the next matmul (W diag(w)) and the attention
                # scale into the query rows: the same products, rounded once differently.
                w_in = layer.input_layernorm.weight
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
                w_post = layer.post_attention_layernorm.weight
                self.layers.append(
                    (
                        t(w_qkv),  # (D, (2 H + 3 Hkv) Dh)
                        t(a.o_proj.weight),  # (H Dh, D)
                        t(torch.cat([m.gate_proj.weight, m.up_proj.weight]) * w_post),  # (D, 2 I)
                        t(m.down_proj.weight),  # (I, D)
                    )
                )

    def _rms(self, x: np.ndarray) -> np.ndarray:
        """LlamaRMSNorm (B n, D) without its weight (folded into the next matmul)."""
        ms = np.einsum("ij,ij->i", x, x)[:, None] * np.float32(1.0 / x.shape[-1])  # (B n, 1)
        return x / np.sqrt(ms + self.eps)

    def _rope_table(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """cos, sin (B, n, 1, Dh) for ``positions`` (B, n), from the model's ``rotary_emb``."""
        top = int(positions.max()) + 1
        if top > len(self.cos):
            size = max(top, 2 * len(self.cos), 1024)
            pos = torch.arange(size)[None]  # (1, size)
            # rotary_emb reads only the dtype and device of its first argument
            cos, sin = self.rotary(torch.zeros(1, 1), pos)  # (1, size, Dh)
            self.cos, self.sin = _numpy(cos[0]), _numpy(sin[0])
        return self.cos[positions][:, :, None], self.sin[positions][:, :, None]

    def _attend(self, q: np.ndarray, kv: WindowKV, mask: np.ndarray | None) -> np.ndarray:
        """softmax(q k^T + mask) v; q (B, H, n, Dh) pre-scaled -> (B, H, n, Dh)."""
        B, H, n, Dh = q.shape
        keys, values = kv.flat()  # (B Hkv, live, Dh) views of the buffers
        if self.kv_heads != H:  # grouped-query attention: each key head serves `rep` query heads
            rep = H // self.kv_heads
            live = keys.shape[1]
            keys = np.repeat(keys.reshape(B, self.kv_heads, live, Dh), rep, 1).reshape(-1, live, Dh)
            values = np.repeat(values.reshape(B, self.kv_heads, live, Dh), rep, 1)
            values = values.reshape(-1, live, Dh)  # (B H, live, Dh)
        scores = q.reshape(B * H, n, Dh) @ keys.transpose(0, 2, 1)  # (B H, n, live)
        if mask is not None:
            scores = (scores.reshape(B, H, n, -1) + mask).reshape(B * H, n, -1)
        scores = np.exp(scores - scores.max(-1, keepdims=True))
        scores /= scores.sum(-1, keepdims=True)
        return (scores @ values).reshape(B, H, n, Dh)

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
        mask = None if attention_mask is None else _numpy(attention_mask.float())
        if mask is None and n > 1:  # causal over the new tokens, all of the past visible
            keep = np.tril(np.ones((n, past + n), bool), past)
            mask = np.where(keep, np.float32(0), np.float32(-np.inf))  # (n, past + n)
        cos, sin = self._rope_table(_numpy(position_ids))  # (B, n, 1, Dh)
        new_cache = [] if not cache else cache
        x = _numpy(embeds.float()).reshape(B * n, D)  # (B n, D)
        for i, (w_qkv, w_o, w_gu, w_down) in enumerate(self.layers):
            proj = (self._rms(x) @ w_qkv).reshape(B, n, -1)  # (B, n, (2H + 3Hkv) Dh)
            a, b = (H + Hkv) * Dh, (H + 2 * Hkv) * Dh
            # RoPE on queries and keys at once: x * cos + rotate_half(x) * sin
            qk = proj[..., :a].reshape(B, n, H + Hkv, Dh) * cos
            qk += proj[..., b:].reshape(B, n, H + Hkv, Dh) * sin  # (B, n, H + Hkv, Dh)
            q = qk[:, :, :H].transpose(0, 2, 1, 3)  # (B, H, n, Dh), pre-scaled by Dh^-0.5
            k = qk[:, :, H:].transpose(0, 2, 1, 3)  # (B, Hkv, n, Dh)
            v = proj[..., a:b].reshape(B, n, Hkv, Dh).transpose(0, 2, 1, 3)  # (B, Hkv, n, Dh)
            if cache:
                cache[i].append(k, v)
            else:
                new_cache.append(WindowKV(k, v, self.capacity))
            attn = self._attend(q, new_cache[i], mask)  # (B, H, n, Dh)
            x = x + attn.transpose(0, 2, 1, 3).reshape(B * n, H * Dh) @ w_o  # (B n, D)
            gu = self._rms(x) @ w_gu  # (B n, 2 I)
            inter = gu.shape[-1] // 2
            g, up = gu[:, :inter], gu[:, inter:]  # (B n, I) each
            # silu(g) = g * sigmoid(g), sigmoid(g) = (1 + tanh(g / 2)) / 2: no overflow in exp
            silu = g * (np.tanh(g * np.float32(0.5)) * np.float32(0.5) + np.float32(0.5))
            x = x + (silu * up) @ w_down  # (B n, D)
        hidden = (self.norm_w * self._rms(x)).reshape(B, n, D)
        return torch.from_numpy(hidden), new_cache
