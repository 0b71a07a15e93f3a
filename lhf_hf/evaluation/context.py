"""The model's sliding context during a rollout (docs/design.md 7): sliding-window attention over the
stream of tokens, kept as a KV cache or recomputed.

Semantics.  A rollout is one stream of tokens (DICP: a query-action token ``Q`` after every
transition token ``T`` but the last).  Every token attends to itself and the tokens just before it,
``W`` tokens in all: ``W = K`` for AD/DPT and, for DICP, ``2K - 1`` for a ``T`` and ``2K`` for a ``Q``
token (what the last ``T`` and ``Q`` tokens of a training window of ``K`` transitions see).  This is
sliding-window attention in every layer (as in Mistral): a token's keys and values in layer l depend on
its own window in layer l - 1 only, never on anything later, so

- ``mode="cache"`` (default, fast): the Llama KV cache.  Each token's keys and values are computed once,
  when it is appended; tokens that no new token can see any more are evicted; when two tokens are
  appended at once (DICP's ``Q, T``), a mask hides from the later one the oldest token only the earlier
  one sees.  RoPE makes attention depend on relative positions only, so with absolute, ever-increasing
  ``position_ids`` the kept keys never need recomputation.  This is *exactly* the semantics above.
- ``mode="recompute"``: the same function without a cache, the reference of the cache's exactness and
  of its speed: every call re-encodes the last ``R = num_hidden_layers * (W_max - 1) + n`` tokens from
  their embeddings with a banded attention mask.  ``R`` is the receptive field: the newest tokens'
  outputs depend on nothing older (each layer reaches ``W_max - 1`` tokens further back), so they are
  exact although the oldest tokens of the recomputed span lack their own history.  Tested: identical
  actions to ``cache`` for paper-size (4-layer) models, DICP included.
- ``mode="window"``: the reference code's protocol, a different function for deeper models: every call
  re-encodes only the last window (``K`` transitions) from scratch with causal attention, so the window's
  oldest token sees nothing before it, as in a training window.  For one-layer models, and for any model
  until the window first fills, it equals the other two (tested).

``snapshot`` hands a planner the context's cache without letting it change the context.
"""

from __future__ import annotations

import torch
from transformers import DynamicCache

from lhf_hf.errors import UserError
from lhf_hf.modeling import attention_kernel
from lhf_hf.modeling.attention import band_mask, token_windows
from lhf_hf.training.attention_backend import kernel_unsupported

from .decode import LeanLlama, supported

MODES = ("cache", "recompute", "window")
ENGINES = ("auto", "lean", "hf")  # auto: lean where supported (cache mode), else HF's forward


def trained_mode(model) -> str:
    """The mode that computes the function the model was trained as: ``cache`` (band attention,
    ``ICRLConfig.attention == "band"``) or ``window`` (trained on windows, causal attention)."""
    return "cache" if model.config.attention == "band" else "window"


class Context:
    """The tokens of a batch of independent streams and the backbone's hidden states of new ones.

    max_tokens: ``W`` of a transition token (default: the model's window, see the module doc).
    engine: the cached step's forward: ``auto`` (``decode.LeanLlama``, the same function without HF's
    per-module overhead, wherever the model allows it), ``lean`` (that, or an error saying why not) or
    ``hf`` (``LlamaModel.forward`` with a ``DynamicCache``).  ``recompute`` and ``window`` run HF's
    forward over whole windows; with ``auto`` its attention runs in the C++ attention kernel
    (``lhf_hf.modeling.attention_kernel``, the training kernel's forward: the same function to float32
    rounding, ~5x faster than SDPA at head dim 8 over a 400-token window, BENCHMARKS.md) wherever it
    loads (``engine == "kernel"``), with ``hf`` in the model's own.  ``self.engine`` says which ran.
    """

    def __init__(
        self, model, mode: str = "cache", max_tokens: int | None = None, engine: str = "auto"
    ):
        if mode == "auto":
            mode = trained_mode(model)
        if mode not in MODES:
            raise UserError(f"unknown context mode {mode!r}: one of {MODES}")
        if engine not in ENGINES:
            raise UserError(f"unknown context engine {engine!r}: one of {ENGINES}")
        self.model = model
        self.mode = mode
        # the cached step's forward: the lean exact decoder (``decode.py``) when the model allows it
        why_not = supported(model)
        if engine == "lean" and why_not is not None:
            raise UserError(f"engine='lean' cannot run this model: {why_not}")
        use_lean = mode == "cache" and engine != "hf" and why_not is None
        use_kernel = (
            mode != "cache"
            and engine == "auto"
            and kernel_unsupported(model.config, next(model.parameters()).device) is None
        )
        self.engine = "lean" if use_lean else "kernel" if use_kernel else "hf"
        self.lean = LeanLlama(model) if use_lean else None
        c = model.config
        self.dicp = c.objective == "dicp"
        # a transition token's window (``token_windows``; DICP: a window of K transitions ends with
        # the transition token whose action is predicted, 2K - 1 tokens before the query-action
        # token of the new action is added)
        self.max_tokens = max_tokens or int(token_windows(c.context_length, self.dicp, 1)[0])
        self.cache: DynamicCache | list | None = None  # list of WindowKV with the lean engine
        self.embeds: torch.Tensor | None = None  # (B, L, D) recompute / window modes
        self.pos = 0  # stream position of the next token
        self.start = 0  # stream position of the oldest kept token
        self.windows = torch.zeros(0, dtype=torch.long)  # (L,) each kept token's W
        self.length = 0  # tokens kept

    def _windows(self, n: int, is_query) -> torch.Tensor:
        q = torch.zeros(n, dtype=torch.bool) if is_query is None else torch.as_tensor(is_query)
        return self.max_tokens + q.long()  # (n,) a query-action token sees one token more

    # ------------------------------------------------------------------ append
    @torch.no_grad()
    def append(self, embeds: torch.Tensor, is_query=None) -> torch.Tensor:
        """Add tokens (B, n, D) (``is_query`` (n,) bool marks DICP query-action tokens); return their
        hidden states (B, n, D)."""
        B, n, _ = embeds.shape
        win = self._windows(n, is_query)  # (n,)
        new_pos = torch.arange(self.pos, self.pos + n)  # (n,)
        if self.mode == "cache":
            hidden = self._append_cached(embeds, new_pos, win)
        elif self.mode == "recompute":
            hidden = self._append_recompute(embeds, new_pos, win)
        else:
            hidden = self._append_window(embeds)
        self.pos += n
        return hidden

    def _append_cached(self, embeds, new_pos, win) -> torch.Tensor:
        B, n, _ = embeds.shape
        if self.cache is None and self.lean is None:
            self.cache = DynamicCache()
        # keep the cached tokens that some new token still sees
        self._evict(int((new_pos - win + 1).min()))
        k_pos = torch.arange(self.start, self.pos + n)  # (C + n,)
        mask = None  # one new token sees everything kept: plain causal attention is exact
        if n > 1:  # a later new token may not see the oldest kept token(s)
            mask = band_mask(new_pos, win, k_pos, embeds.dtype)[None, None].expand(B, 1, n, -1)
        if self.lean is not None:  # self.cache: one WindowKV per layer
            hidden, self.cache = self.lean(embeds, new_pos[None].expand(B, n), self.cache, mask)
            self.length += n
            return hidden
        hidden, self.cache = self.model.run_backbone(
            embeds,
            backbone_cache=self.cache,
            position_ids=new_pos[None].expand(B, n),
            use_cache=True,
            attention_mask=mask,
        )
        self.length += n
        return hidden

    def _evict(self, first: int) -> None:
        drop = first - self.start
        if drop > 0 and self.cache is not None:
            if self.lean is not None:
                for kv in self.cache:
                    kv.evict(drop)
            else:
                for layer in self.cache.layers:
                    layer.keys = layer.keys[:, :, drop:]  # (B, H, L, Dh): the oldest tokens go
                    layer.values = layer.values[:, :, drop:]
            self.start += drop
            self.length -= drop

    def _receptive_field(self, n: int) -> int:
        w_max = self.max_tokens + (1 if self.dicp else 0)
        return self.model.config.num_hidden_layers * (w_max - 1) + n

    def _append_recompute(self, embeds, new_pos, win) -> torch.Tensor:
        B, n, _ = embeds.shape
        self._keep(embeds, win, self._receptive_field(n))
        k_pos = torch.arange(self.start, self.pos + n)  # (L,)
        mask = band_mask(k_pos, self.windows, k_pos, embeds.dtype)  # (L, L)
        L = len(k_pos)
        hidden, _ = self._run_window(
            self.embeds,
            position_ids=k_pos[None].expand(B, L),
            use_cache=False,
            attention_mask=mask[None, None].expand(B, 1, L, L),
        )
        return hidden[:, -n:]

    def _append_window(self, embeds) -> torch.Tensor:
        B, n, _ = embeds.shape
        self._keep(embeds, self._windows(n, None), self.max_tokens)
        L = self.length
        pos = torch.arange(L).unsqueeze(0).expand(B, L)
        # the window's keys and values are kept for a planner (``snapshot``): encoding the window
        # again there would double the cost of every planned step
        hidden, self.cache = self._run_window(self.embeds, position_ids=pos, use_cache=True)
        return hidden[:, -n:]

    def _run_window(self, embeds, **kwargs):
        """``run_backbone`` over a whole window (``recompute``, ``window``); its attention in the C++
        kernel with ``engine == "kernel"`` (the class docstring)."""
        if self.engine != "kernel":
            return self.model.run_backbone(embeds, **kwargs)
        config = self.model.backbone.config  # the attention layers read its implementation
        saved, config._attn_implementation = config._attn_implementation, attention_kernel.NAME
        try:
            return self.model.run_backbone(embeds, **kwargs)
        finally:
            config._attn_implementation = saved

    def _keep(self, embeds, win, keep: int) -> None:
        """Append token embeddings (B, n, D) and keep the last ``keep``."""
        full = embeds if self.embeds is None else torch.cat([self.embeds, embeds], dim=1)
        windows = torch.cat([self.windows, win])
        self.embeds, self.windows = full[:, -keep:], windows[-keep:]  # (B, <=keep, D), (<=keep,)
        self.length = self.embeds.shape[1]
        self.start = self.pos + len(win) - self.length

    # ------------------------------------------------------------------ planning
    @torch.no_grad()
    def snapshot(self) -> tuple[DynamicCache, int, int]:
        """(cache of the kept tokens, its length, the next token's stream position) for a planner.

        The cache shares the context's tensors (appending to it creates new ones), so planning never
        changes the context.  ``window``: the last window's encoding (kept by ``append``, positions
        from 0 as in a training window); ``recompute``: the kept tokens are encoded here."""
        if self.mode in ("cache", "window"):
            layers = self.cache if self.lean is not None else self.cache.layers
            data = [(layer.keys, layer.values) for layer in layers]
            pos = self.pos if self.mode == "cache" else self.length
            return DynamicCache(ddp_cache_data=data), self.length, pos
        B, L, _ = self.embeds.shape  # recompute
        k_pos = torch.arange(self.start, self.pos)  # (L,)
        mask = band_mask(k_pos, self.windows, k_pos, self.embeds.dtype)
        _, cache = self._run_window(
            self.embeds,
            position_ids=k_pos[None].expand(B, L),
            use_cache=True,
            attention_mask=mask[None, None].expand(B, 1, L, L),
        )
        return cache, L, self.pos
