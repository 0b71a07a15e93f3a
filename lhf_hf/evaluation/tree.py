"""The backbone over a DICP planner's tree of imagined tokens (``planning.py``): two engines, one
function.

The planner appends, at each depth, ``nb`` groups of ``per_beam`` new tokens (beam-major: a beam's
imagined transition token, then its query-action tokens) to a snapshot of the rollout's context
(``forward``), then says which beams go on, each through one token of its group (``select``).  A
new token sees the context's tokens in its window (the oldest drop out as its path grows), its
beam's path (the tokens of earlier depths on the way to it), the first ``shared`` tokens of its
group and itself, at the stream position it would have on a linear path.

- ``TorchTree`` (``engine="torch"``, the reference): ``LlamaModel.forward`` on the context's KV
  cache with the tree as an additive mask over the context and every tree token so far (SDPA
  computes every score and the mask throws most away: at depth 16 on a 400-token context a token
  sees ~400 of ~1,300 keys).
- ``KernelTree`` (``engine="kernel"``): the same layers written out in a few torch ops each, with
  the attention in a C++ kernel that computes only the visible scores and carries each beam's
  path from depth to depth (``lhf_hf.modeling.tree_attention``); the context's keys and values are
  transposed once per planned step, no cache is copied per depth.  Equal to the reference to
  float32 rounding (RMSNorm weights folded into the next matmul, RoPE's ``rotate_half`` as extra
  rows of the projection, as ``decode.LeanLlama``); tested: the same hidden states, planned
  actions, scores and imagined transitions.

``engine="auto"`` takes the kernel wherever ``kernel_unsupported`` finds no reason against it.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from lhf_hf.errors import UserError
from lhf_hf.modeling import tree_attention

from .context import Context
from .decode import supported

ENGINES = ("auto", "kernel", "torch")


def kernel_unsupported(model) -> str | None:
    """Why the kernel engine cannot run ``model``'s tree (None when it can)."""
    why = supported(model)  # a float32 LlamaModel on the CPU, in eval mode, silu, default RoPE
    if why is not None:
        return why
    c = model.backbone.config
    p = next(model.backbone.parameters())
    head_dim = getattr(c, "head_dim", None) or c.hidden_size // c.num_attention_heads
    return tree_attention.unsupported(head_dim, p.dtype, p.device)


def resolve_engine(model, engine: str = "auto") -> str:
    """``kernel`` or ``torch``: ``engine`` with ``auto`` decided (a UserError when ``kernel`` is
    asked for and cannot run, naming the reason)."""
    if engine not in ENGINES:
        raise UserError(f"unknown planner engine {engine!r}: one of {ENGINES}")
    if engine == "torch":
        return "torch"
    why = kernel_unsupported(model)
    if why is None:
        return "kernel"
    if engine == "kernel":
        raise UserError(f"the planner's kernel engine cannot run this model: {why}")
    return "torch"


def make_tree(model, context: Context, beams: int, group: int, path: int, engine: str = "auto"):
    """A tree over a snapshot of ``context``: at most ``beams`` groups of ``group`` new tokens per
    ``forward``, paths of at most ``path`` tokens."""
    if resolve_engine(model, engine) == "kernel":
        return KernelTree(model, context, beams, group, path)
    return TorchTree(model, context)


def _context_window(L0: int, window: int, offsets, is_query) -> torch.Tensor:
    """(n,) the first context token each new token sees (``L0``: none): every token sees at most
    its training window, a query-action token one more than a transition token, so the oldest
    context tokens drop out as the path grows (its own path it sees whole)."""
    win = window + is_query.long()  # (n,)
    return (L0 + offsets + 1 - win).clamp(min=0, max=L0)  # (n,)


class TorchTree:
    """Appends tree tokens to a snapshot of the context through ``LlamaModel.forward``.

    ``forward`` appends a group of new tokens to every beam; ``select`` says which beams go on, each
    through one of its group's tokens (after the group's ``shared`` ones)."""

    engine = "torch"

    def __init__(self, model, context: Context):
        self.model = model
        self.cache, self.L0, self.pos0 = context.snapshot()
        self.window = context.max_tokens  # tokens a transition token sees (its own included)
        self.n_tree = 0
        self.paths = None  # (B, nb, plen) tree indices of each beam's path; None: no path yet
        self.last = None  # (first tree index, per_beam, shared) of the last forward

    def forward(self, embeds, offsets, is_query, shared: int) -> torch.Tensor:
        """embeds (B, n, D), n = nb * per_beam new tokens, a group per beam; offsets, is_query
        (per_beam,): the group's path offsets (0 = the first token after the context) and
        query-action flags; shared: the group's first tokens that every later one sees.  Returns
        hidden states (B, n, D)."""
        B, n, _ = embeds.shape
        per_beam = len(offsets)
        nb = n // per_beam
        paths = torch.zeros(B, nb, 0, dtype=torch.long) if self.paths is None else self.paths
        anc = torch.zeros(B, nb, self.n_tree, dtype=torch.bool)
        anc.scatter_(2, paths, True)  # (B, nb, n_tree) each beam's path
        ancestors = anc.repeat_interleave(per_beam, dim=1)  # (B, n, n_tree)
        t = torch.arange(per_beam)
        links = (t[None, :] < torch.clamp(t, max=shared)[:, None]) | torch.eye(per_beam, dtype=bool)
        new_links = torch.block_diag(*[links] * nb)  # (n, n) each token: its group's visible ones
        offsets, is_query = offsets.repeat(nb), is_query.repeat(nb)  # (n,)
        drop = _context_window(self.L0, self.window, offsets, is_query)
        ctx = torch.arange(self.L0)[None, :] >= drop[:, None]  # (n, L0)
        mask = torch.cat(
            [ctx.expand(B, n, self.L0), ancestors, new_links.expand(B, n, n)], dim=2
        )  # (B, n, L0 + n_tree + n)
        pos = (self.pos0 + offsets).expand(B, n)
        # an additive float mask: CPU SDPA converts a boolean one on every layer
        bias = torch.zeros(mask.shape, dtype=embeds.dtype).masked_fill_(~mask, float("-inf"))
        hidden, self.cache = self.model.run_backbone(
            embeds,
            backbone_cache=self.cache,
            position_ids=pos,
            use_cache=True,
            attention_mask=bias[:, None],
        )
        self.last = (self.n_tree, per_beam, shared)
        self.paths = paths
        self.n_tree += n
        return hidden

    def select(self, parent: torch.Tensor, token: torch.Tensor) -> None:
        """The beams of the next ``forward``: (B, keep) each one's beam in the last ``forward``
        and the token of that beam's group it continues with."""
        base, per_beam, shared = self.last
        B, keep = parent.shape
        first = base + parent * per_beam  # (B, keep) tree index of each parent's group
        own = [first + s for s in range(shared)] + [first + token]  # the shared tokens, the token
        b = torch.arange(B)[:, None]
        self.paths = torch.cat([self.paths[b, parent], *(i[:, :, None] for i in own)], dim=2)


class KernelTree:
    """The backbone's layers over tree tokens with the tree attention kernel (module docstring).

    Weights are fused at construction (per planned step: ~0.1 ms).  Each layer keeps every beam's
    path (keys and values) in the kernel's path buffers, two sets used in turn: a ``forward`` builds
    this depth's from the previous depth's as ``select`` chose (``tree_attention``).  Every depth
    and layer writes its intermediates into buffers allocated once for the largest depth: a fresh
    multi-megabyte tensor per op is a fresh ``mmap`` whose pages fault in on first touch, which
    made the MLP's (B n, 2 I) product several times slower than the matmul itself (profiled,
    B 48, Darkroom-Permuted)."""

    engine = "kernel"

    def __init__(self, model, context: Context, beams: int, group: int, path: int):
        bb = model.backbone
        c = bb.config
        H, Hkv = c.num_attention_heads, c.num_key_value_heads
        self.heads, self.kv_heads = H, Hkv
        self.head_dim = Dh = getattr(c, "head_dim", None) or c.hidden_size // H
        self.scale = Dh**-0.5
        self.eps = c.rms_norm_eps
        self.rotary = bb.rotary_emb
        self.norm_w = bb.norm.weight.detach()
        cache, self.L0, self.pos0 = context.snapshot()
        self.window = context.max_tokens
        half = Dh // 2

        def rotate_rows(w: torch.Tensor, heads: int) -> torch.Tensor:
            # rows of rotate_half(W x) = (P W) x: per head, [-w[half:], w[:half]]
            w = w.view(heads, Dh, -1)  # (heads, Dh, D)
            return torch.cat([-w[:, half:], w[:, :half]], dim=1).reshape(heads * Dh, -1)

        self.layers = []
        with torch.no_grad():
            for layer, kv in zip(bb.layers, cache.layers, strict=True):
                a, m = layer.self_attn, layer.mlp
                w_qkv = (
                    torch.cat(
                        [
                            a.q_proj.weight,
                            a.k_proj.weight,
                            a.v_proj.weight,
                            rotate_rows(a.q_proj.weight, H),
                            rotate_rows(a.k_proj.weight, Hkv),
                        ]
                    )
                    * layer.input_layernorm.weight
                )  # ((2 H + 3 Hkv) Dh, D): RMSNorm's weight folded
                w_gu = torch.cat([m.gate_proj.weight, m.up_proj.weight])
                w_gu = w_gu * layer.post_attention_layernorm.weight  # (2 I, D)
                B = kv.keys.shape[0]
                self.layers.append(
                    {
                        "qkv": w_qkv.t().contiguous(),  # (D, (2 H + 3 Hkv) Dh)
                        "o": a.o_proj.weight.t().contiguous(),  # (H Dh, D)
                        "gu": w_gu.t().contiguous(),  # (D, 2 I)
                        "down": m.down_proj.weight.t().contiguous(),  # (I, D)
                        "kct": tree_attention.transposed(kv.keys),  # (B, Hkv, Dh, Lp)
                        "vct": tree_attention.transposed(kv.values),
                        # (keys, values) of every beam's path: this depth's, the previous one's
                        "paths": [
                            tree_attention.path_buffers(B, Hkv, beams, Dh, path + group)
                            for _ in range(2)
                        ],
                    }
                )
        D, inter = c.hidden_size, c.intermediate_size
        rows = B * beams * group
        widths = {"x": D, "sq": D, "h": D, "proj": (2 * H + 3 * Hkv) * Dh, "qk": (H + Hkv) * Dh,
                  "att": H * Dh, "gu": 2 * inter, "act": inter}  # fmt: skip
        self.widths = widths
        self.work = {name: torch.empty(rows * w) for name, w in widths.items()}
        self.depth = 0  # forwards so far: this depth writes paths[depth % 2]
        self.plen = 0  # path length of the next forward's beams
        self.parent = self.src_col = None  # (B, nb) int32, set by select
        self.last = None  # (per_beam, shared) of the last forward

    def _buf(self, name: str, *shape: int) -> torch.Tensor:
        """The first prod(shape) elements of work buffer ``name`` as a contiguous tensor."""
        return self.work[name][: math.prod(shape)].view(shape)

    def _rms(self, x: torch.Tensor, weight: torch.Tensor | None = None, out=None) -> torch.Tensor:
        """LlamaRMSNorm's formula, ``x * rsqrt(mean(x^2) + eps)`` (times ``weight``), into ``out``."""
        ms = torch.square(x, out=self._buf("sq", *x.shape)).mean(-1, keepdim=True)  # (N, 1)
        y = torch.mul(x, ms.add_(self.eps).rsqrt_(), out=out)
        return y if weight is None else y.mul_(weight)

    def forward(self, embeds, offsets, is_query, shared: int) -> torch.Tensor:
        """``TorchTree.forward``'s arguments and result."""
        B, n, D = embeds.shape
        per_beam = len(offsets)
        nb = n // per_beam
        H, Hkv, Dh = self.heads, self.kv_heads, self.head_dim
        N, a, b = B * n, (H + Hkv) * Dh, (H + 2 * Hkv) * Dh
        ctx_lo = _context_window(self.L0, self.window, offsets, is_query).repeat(nb)  # (n,)
        ctx_lo = ctx_lo.to(torch.int32)
        pos = (self.pos0 + offsets).repeat(nb)[None]  # (1, n)
        cos, sin = self.rotary(embeds[:1], pos)  # (1, n, Dh)
        # materialised per head: a broadcast in the inner dimensions makes the products ~4x slower
        cos, sin = (t[:, :, None].expand(1, n, H + Hkv, Dh).contiguous() for t in (cos, sin))
        x = self._buf("x", N, D).copy_(embeds.reshape(N, D))  # the residual stream
        h = self._buf("h", N, D)
        proj = self._buf("proj", N, self.widths["proj"])
        qk = self._buf("qk", B, n, H + Hkv, Dh)
        att = self._buf("att", B, n, H, Dh)
        gu = self._buf("gu", N, self.widths["gu"])
        inter = self.widths["act"]
        act = self._buf("act", N, inter)
        dst, src = self.depth % 2, (self.depth + 1) % 2
        for w in self.layers:
            torch.mm(self._rms(x, out=h), w["qkv"], out=proj)  # (N, (2 H + 3 Hkv) Dh)
            # RoPE on queries and keys at once: x * cos + rotate_half(x) * sin
            torch.mul(proj[:, :a].view(B, n, H + Hkv, Dh), cos, out=qk)
            qk.addcmul_(proj[:, b:].view(B, n, H + Hkv, Dh), sin)  # (B, n, H + Hkv, Dh)
            tree_attention.forward(
                qk[:, :, :H], qk[:, :, H:], proj[:, a:b].view(B, n, Hkv, Dh),
                w["kct"], w["vct"], self.L0,
                w["paths"][src] if self.plen else None, w["paths"][dst],
                self.parent, self.src_col, self.plen, ctx_lo, per_beam, shared, self.scale,
                out=att,
            )  # fmt: skip  # (B, n, H, Dh)
            x.addmm_(att.view(N, H * Dh), w["o"])  # (N, D)
            torch.mm(self._rms(x, out=h), w["gu"], out=gu)  # (N, 2 I)
            gate, up = gu[:, :inter], gu[:, inter:]
            torch.mul(F.silu(gate, inplace=True), up, out=act)
            x.addmm_(act, w["down"])
        self.depth += 1
        self.last = (per_beam, shared)
        return self._rms(x, self.norm_w, out=torch.empty(N, D)).view(B, n, D)

    def select(self, parent: torch.Tensor, token: torch.Tensor) -> None:
        """``TorchTree.select``: the kernel builds the chosen paths at the next ``forward``."""
        per_beam, shared = self.last
        self.src_col = (self.plen + token).to(torch.int32)  # the token's column in the last paths
        self.parent = parent.to(torch.int32)
        self.plen += shared + 1
