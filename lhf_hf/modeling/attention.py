"""Which tokens a token attends to: the sliding-window ("band") semantics shared by training with
``attention="band"`` and the streaming rollout context (``lhf_hf.evaluation.context``).

A token at stream position ``p`` with window ``w`` attends to the tokens at positions ``p - w + 1 ..
p`` in every layer.  ``w`` is what the last token of a training window of ``K`` transitions sees:
``K`` for AD / DPT; for DICP (a query-action token after every transition token) ``2K - 1`` for a
transition token and ``2K`` for a query-action token.
"""

from __future__ import annotations

import torch


def band_mask(q_pos, q_win, k_pos, dtype=torch.float32) -> torch.Tensor:
    """Additive attention bias (n, m): query i (stream position ``q_pos[i]``, window ``q_win[i]``) may
    attend to key j iff ``q_pos[i] - q_win[i] < k_pos[j] <= q_pos[i]``.

    A float bias, not a boolean mask: CPU SDPA converts a boolean mask on every layer."""
    lo = (q_pos - q_win)[:, None]  # (n, 1)
    ok = (k_pos[None, :] > lo) & (k_pos[None, :] <= q_pos[:, None])  # (n, m)
    return torch.zeros(ok.shape, dtype=dtype).masked_fill_(~ok, float("-inf"))


def token_windows(context_length: int, dicp: bool, n_transitions: int) -> torch.Tensor:
    """(n_tokens,) the window of every token of ``n_transitions`` transitions' tokens, in order."""
    K = context_length
    if not dicp:
        return torch.full((n_transitions,), K)
    return torch.tensor([2 * K - 1, 2 * K]).repeat(n_transitions)  # [T_0, Q_0, T_1, Q_1, ...]
