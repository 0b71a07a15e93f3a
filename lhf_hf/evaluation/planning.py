"""DICP planning (paper appendix "DICP"; DESIGN.md 7): the planner takes the model as an argument.

Both planners extend a *branch* of the rollout's context (``Context.repeat`` / ``select``) with
query-action tokens ``Q(s, a)`` and imagined transition tokens ``T(s, a, r_hat, s_hat)``, exactly the
token sequence of training, so the real context is encoded once and reused by every beam.

- ``beam_search`` (discrete actions): beams start from the current state; every depth expands each
  beam with every action, scores a candidate by the sum of predicted rewards along its path, keeps the
  best ``beams`` (ties broken by the policy's order: more probable actions first, then earlier beams),
  and imagines the next state with the next-state head.  One backbone call per depth: the imagined
  transition token of the previous depth and the candidates' query-action tokens go in together.
  Returns the first action of the best beam.
- ``greedy_search`` (continuous actions): the policy mean and ``samples - 1`` draws from the policy;
  the candidate with the highest predicted reward wins.
"""

from __future__ import annotations

import numpy as np
import torch

from .context import Context


def _rank_candidates(score: torch.Tensor, policy_rank: torch.Tensor, keep: int) -> torch.Tensor:
    """Indices (B, keep) of the best candidates by score; ties by ``policy_rank`` (lower first),
    then by position.  score, policy_rank: (B, N)."""
    order = torch.argsort(policy_rank, dim=1, stable=True)  # secondary key first
    by_score = torch.argsort(score.gather(1, order), dim=1, descending=True, stable=True)
    return order.gather(1, by_score)[:, :keep]


@torch.no_grad()
def beam_search(
    model,
    context: Context,
    states: torch.Tensor,
    logits: torch.Tensor,
    horizon: int,
    beams: int,
) -> torch.Tensor:
    """First action (B,) of the best imagined path of ``horizon`` steps.

    context: the rollout's context, ending with the current transition token.
    states: (B, S) current states; logits: (B, A) the policy's logits at the current token.
    """
    B, A = logits.shape
    dev = logits.device
    nb = 1
    beam_ctx = context
    beam_state = states  # (B * nb, S)
    beam_score = torch.zeros(B, 1, device=dev)  # (B, nb)
    beam_first = None  # (B, nb) first action of each beam
    pending = None  # the imagined transition token each beam still has to append
    policy = logits  # (B * nb, A)
    for depth in range(horizon):
        actions = torch.arange(A, device=dev).repeat(B * nb)  # (B * nb * A,) every action per beam
        cand_ctx = beam_ctx.repeat(A)  # rows: (b, beam, action)
        q = model.embed_query_actions(
            beam_state.repeat_interleave(A, 0)[:, None], actions[:, None]
        )  # (B * nb * A, 1, D)
        tokens = q if pending is None else torch.cat([pending.repeat_interleave(A, 0), q], dim=1)
        hidden = cand_ctx.append(tokens)  # (B * nb * A, 1 or 2, D)
        if pending is not None:  # the policy at the imagined state orders this depth's candidates
            policy = model.action_distribution(hidden[::A, :1])["action_logits"][
                :, 0
            ]  # (B * nb, A)
        dyn = model.dynamics(hidden[:, -1:])
        r_hat = dyn["reward_pred"][:, 0]  # (B * nb * A,)
        s_hat = model.predicted_next_states(dyn)[:, 0]  # (B * nb * A, S)
        score = beam_score.repeat_interleave(A, 1) + r_hat.view(B, nb * A)  # (B, nb * A)
        # policy order: rank of each action in its beam's policy (0 = most probable)
        rank_in_beam = torch.argsort(
            torch.argsort(-policy, dim=1, stable=True), dim=1
        )  # (B * nb, A)
        policy_rank = (
            rank_in_beam.view(B, nb, A) * nb + torch.arange(nb, device=dev)[None, :, None]
        ).view(B, nb * A)
        first = (
            actions.view(B, nb * A) if beam_first is None else beam_first.repeat_interleave(A, 1)
        )
        keep = min(beams, nb * A)
        idx = _rank_candidates(score, policy_rank, keep)  # (B, keep)
        beam_first, beam_score = first.gather(1, idx), score.gather(1, idx)
        if depth == horizon - 1:
            break
        flat = (torch.arange(B, device=dev)[:, None] * nb * A + idx).reshape(-1)  # (B * keep,)
        beam_ctx = cand_ctx.select(flat)
        prev_state = beam_state.repeat_interleave(A, 0)[flat]
        pending = model.embed_transitions(
            states=s_hat[flat][:, None],
            prev_states=prev_state[:, None],
            prev_actions=actions[flat][:, None],
            prev_rewards=r_hat[flat][:, None],
            prev_dones=torch.zeros(len(flat), 1, dtype=torch.bool, device=dev),
            has_prev=torch.ones(len(flat), 1, dtype=torch.bool, device=dev),
        )  # (B * keep, 1, D)
        beam_state, nb = s_hat[flat], keep
    return beam_first[:, 0]


@torch.no_grad()
def greedy_search(
    model,
    context: Context,
    states: torch.Tensor,
    mean: torch.Tensor,
    log_std: torch.Tensor,
    samples: int,
    rng: np.random.Generator,
    low: float = -1.0,
    high: float = 1.0,
) -> torch.Tensor:
    """(B, A) the candidate action with the highest predicted reward (policy mean + samples)."""
    B, A = mean.shape
    z = torch.as_tensor(rng.standard_normal((B, samples - 1, A)), dtype=mean.dtype)
    cands = torch.cat(
        [mean[:, None], mean[:, None] + log_std.exp()[:, None] * z], dim=1
    )  # (B, n, A)
    cands = cands.clamp(low, high)
    q = model.embed_query_actions(
        states.repeat_interleave(samples, 0)[:, None], cands.reshape(B * samples, 1, A)
    )  # (B * n, 1, D)
    hidden = context.repeat(samples).append(q)
    r_hat = model.dynamics(hidden)["reward_pred"].view(B, samples)
    best = r_hat.argmax(1)  # (B,)
    return cands[torch.arange(B), best]
