"""The model's sliding context during a rollout: a KV cache, or a full recompute of the window.

``Context`` holds, for a batch of independent streams, the tokens the model currently sees (at most
``config.max_tokens`` minus DICP's missing last query-action token) and returns the backbone's
hidden states of newly appended tokens.

- ``use_cache=True``: the Llama KV cache; tokens older than the window are dropped from the cache.
  RoPE makes attention depend on relative positions only, so with explicit, ever-increasing
  ``position_ids`` the kept keys need no recomputation.  The first layer is then exactly the
  window's; deeper layers' cached keys were computed when their token was appended and so carry
  information from up to ``num_hidden_layers`` windows back ("streaming" attention, as in
  Transformer-XL).  Until the window first fills, and for one-layer models always, this equals the
  recompute below (tested).
- ``use_cache=False``: every call re-runs the backbone over the window's token embeddings from
  scratch, exactly the training distribution (a window of K transitions); the reference code's
  behaviour and the baseline of the cache benchmark.

``snapshot`` hands a planner the window's cache without letting it change the context.
"""

from __future__ import annotations

import torch
from transformers import DynamicCache


class Context:
    def __init__(self, model, use_cache: bool = True, max_tokens: int | None = None):
        self.model = model
        self.use_cache = use_cache
        # DICP: a window of K transitions ends with the transition token whose action is predicted,
        # so it holds 2K - 1 tokens before the query-action token of the new action is added.
        c = model.config
        self.max_tokens = max_tokens or (
            2 * c.context_length - 1 if c.objective == "dicp" else c.context_length
        )
        self.cache: DynamicCache | None = None
        self.embeds: torch.Tensor | None = None  # (B, L, D) recompute mode
        self.pos = 0  # absolute position of the next token (cache mode)
        self.length = 0  # tokens in the window

    # ------------------------------------------------------------------ append
    @torch.no_grad()
    def append(self, embeds: torch.Tensor) -> torch.Tensor:
        """Add tokens (B, n, D); return their hidden states (B, n, D)."""
        n = embeds.shape[1]
        if self.use_cache:
            pos = torch.arange(self.pos, self.pos + n, device=embeds.device).unsqueeze(0)  # (1, n)
            pos = pos.expand(embeds.shape[0], n)
            if self.cache is None:
                self.cache = DynamicCache()
            self._evict(self.max_tokens - n)  # room for the new tokens: they see a full window
            hidden, self.cache = self.model.run_backbone(
                embeds, past_key_values=self.cache, position_ids=pos, use_cache=True
            )
            self.pos += n
            self.length += n
            return hidden
        self.embeds = embeds if self.embeds is None else torch.cat([self.embeds, embeds], dim=1)
        self.embeds = self.embeds[:, -self.max_tokens :]  # (B, <=L, D)
        self.length = self.embeds.shape[1]
        L = self.length
        pos = torch.arange(L, device=embeds.device).unsqueeze(0).expand(embeds.shape[0], L)
        hidden, _ = self.model.run_backbone(self.embeds, position_ids=pos, use_cache=False)
        return hidden[:, -n:]

    def _evict(self, keep: int) -> None:
        drop = self.length - max(keep, 0)
        if drop > 0:
            for layer in self.cache.layers:
                layer.keys = layer.keys[:, :, drop:]  # (B, H, L, Dh): the oldest tokens go
                layer.values = layer.values[:, :, drop:]
            self.length -= drop

    # ------------------------------------------------------------------ planning
    @torch.no_grad()
    def snapshot(self) -> tuple[DynamicCache, int, int]:
        """(cache of the current window, its length, the next token's position) for a planner.

        The cache shares the context's tensors (appending to it creates new ones), so planning never
        changes the context; in recompute mode the window is encoded once here."""
        if self.use_cache:
            data = [(layer.keys, layer.values) for layer in self.cache.layers]
            return DynamicCache(ddp_cache_data=data), self.length, self.pos
        L = self.embeds.shape[1]
        pos = torch.arange(L).unsqueeze(0).expand(self.embeds.shape[0], L)
        _, cache = self.model.run_backbone(self.embeds, position_ids=pos, use_cache=True)
        return cache, L, L
