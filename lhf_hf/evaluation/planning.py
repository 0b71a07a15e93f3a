"""DICP planning (paper appendix "DICP"; docs/design.md 7): the planner takes the model as an argument.

Imagined paths are a *tree* of tokens appended to the rollout's cached context: query-action tokens
``Q(s, a)`` and imagined transition tokens ``T(s, a, r_hat, s_hat)``, the token sequence of training.
All beams of all tasks extend the one shared context in a single backbone call per depth, with a
tree attention mask (each token sees the context window and its own path only) and the positions it
would have on a linear path, so the context is encoded once per real step and never copied per beam
(the reference code recomputes the context for every beam).  ``tree.py`` runs the backbone over the
tree: a C++ kernel that computes only the scores each token sees (``engine="kernel"``, the default
where the model allows it) or ``LlamaModel.forward`` with the mask (``engine="torch"``, the
reference); the search and its choices are the same.

- ``beam_search`` (discrete actions): beams start from the current state; each depth expands every
  beam with every action, scores a candidate by the sum of predicted rewards along its path, keeps
  the best ``beams`` (ties below depth 0: by action index within a beam, then the earlier beam,
  as the reference's stable sort; ``ties="policy"``, ours: the more probable action first), and
  imagines the next state with the next-state head.  Returns the first action of the best
  path.
- ``greedy_search`` (continuous actions): the policy mean and ``samples - 1`` draws from the policy;
  the candidate with the highest predicted reward wins.
"""

from __future__ import annotations

import numpy as np
import torch

from lhf_hf.errors import UserError

from .context import Context
from .tree import make_tree


def depth_tokens(actions: int, horizon: int, beams: int) -> list[int]:
    """Imagined tokens of a beam search per depth: ``actions`` query-action tokens at depth 0, then
    each kept beam's transition token and its ``actions`` query-action tokens."""
    out, nb = [actions], 1
    for _ in range(1, horizon):
        nb = min(beams, nb * actions)
        out.append(nb * (1 + actions))
    return out


def imagined_reward(model, dyn: dict, threshold: float | None = None) -> torch.Tensor:
    """(B, N) the reward the search imagines for its candidates: the reward head's most likely
    class (the reference's), or with ``threshold`` a nonzero class only where the head gives it at
    least that probability, else the zero-reward class.  The search maximises over hundreds of
    candidates per step, so a head right on 99.9 % of them still hands it a phantom reward most
    steps (results/planning/dicp_convergence): a threshold is a variant of ours, its own row."""
    if threshold is None:
        return dyn["reward_pred"]
    logits, values = dyn.get("reward_logits"), model.config.reward_values
    if logits is None or not values or 0 not in values:
        raise UserError(
            "a reward threshold needs a reward head over reward classes that include 0 (a "
            "gridworld DICP); this model's reward head regresses the reward"
        )
    p = logits.softmax(-1)  # (B, N, C)
    best = p.argmax(-1)  # (B, N)
    v = torch.tensor(values, dtype=torch.float32)  # (C,)
    unsure = (v[best] != 0) & (p.gather(-1, best[..., None])[..., 0] < threshold)
    return v[torch.where(unsure, values.index(0), best)]


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
    dynamics=None,
    order: str = "argmax",
    generator: torch.Generator | None = None,
    trace: list | None = None,
    engine: str = "auto",
    reward_threshold: float | None = None,
    ties: str = "index",
) -> tuple[torch.Tensor, torch.Tensor]:
    """First action (B,) of the best imagined path of ``horizon`` steps, and its score (B,).

    context: the rollout's context, ending with the current transition token.
    states: (B, S) current states; logits: (B, A) the policy's logits at the current token.
    dynamics: None (the model's reward and next-state heads) or a function (states (B, N, S),
        actions (B, N)) -> (next states, rewards) in numpy, e.g. the environment's own
        (``BatchedTasks.imagine``): the planner's machinery with perfect dynamics, a diagnostic.
    order: how candidates of equal score are ranked at depth 0: ``sample`` (a permutation drawn
        from the policy with ``generator``, Gumbel-top-k: the reference's, so that when no path
        predicts a reward the action is a policy sample) or ``argmax`` (the policy's order).
    ties: how deeper depths rank candidates of equal score: ``index`` (the reference's
        ``ad.py``: candidates laid out beam by beam, the beams in rank order, each beam's actions
        by index, stable-sorted by score; with no reward imagined the kept beams are the first
        beams' children, so from depth 2 on every path starts with the best first action and a
        false reward can redirect few of them) or ``policy`` (a variant of ours: each beam's
        actions in the policy's order at its imagined state, interleaved over the beams, so every
        first action stays in the tree to the last depth; ~5x more candidates whose phantom reward
        changes the chosen action, results/planning/dicp_convergence).
    trace: a list that receives, per depth, what the planner imagined: ``{depth, states (B, N, S),
        actions (B, N), reward (B, N), next_state (B, N, S)}`` for its N candidates (numpy), so a
        diagnosis can hold them against the true dynamics.
    engine: the backbone over the tree (``tree.py``): ``auto`` (the C++ tree attention kernel where
        the model allows it), ``kernel`` (that, or an error saying why not) or ``torch`` (the
        reference: ``LlamaModel.forward`` with a tree mask).
    reward_threshold: imagine a nonzero reward only where the head gives it at least this
        probability (``imagined_reward``; None: the most likely class, the reference's).
    """
    if order not in ("sample", "argmax"):
        raise UserError(f"order must be 'sample' or 'argmax', got {order!r}")
    if ties not in ("index", "policy"):
        raise UserError(f"ties must be 'index' or 'policy', got {ties!r}")
    B, A = logits.shape
    tree = make_tree(
        model, context, beams=min(beams, A ** (horizon - 1)), group=1 + A,
        path=max(2 * horizon - 3, 0), engine=engine,
    )  # fmt: skip
    b_idx = torch.arange(B)[:, None]
    nb = 1
    beam_state = states[:, None]  # (B, nb, S)
    beam_score = torch.zeros(B, 1)
    beam_first = None  # (B, nb)
    beam_T = None  # (B, nb, D) each beam's imagined transition token, appended at the next depth
    policy = logits[:, None]  # (B, nb, A)
    for depth in range(horizon):
        acts = torch.arange(A).expand(B, nb, A)  # (B, nb, A)
        q = model.embed_query_actions(
            beam_state[:, :, None].expand(B, nb, A, -1).reshape(B, nb * A, -1),
            acts.reshape(B, nb * A),
        ).view(B, nb, A, -1)  # (B, nb, A, D)
        per_beam = A if beam_T is None else 1 + A  # [T_j,] Q_j0 .. Q_jA-1
        if beam_T is None:
            embeds = q.reshape(B, nb * A, -1)
        else:
            embeds = torch.cat([beam_T[:, :, None], q], dim=2).reshape(B, nb * per_beam, -1)
        is_query = torch.ones(per_beam, dtype=torch.bool)
        offsets = torch.full((per_beam,), 2 * depth)
        if beam_T is not None:
            is_query[0] = False
            offsets[0] = 2 * depth - 1
        # the beam's query-action tokens follow its transition token: they see it
        shared = 0 if beam_T is None else 1
        hidden = tree.forward(embeds, offsets, is_query, shared)
        hidden = hidden.view(B, nb, per_beam, -1)
        if beam_T is not None and ties == "policy":  # the policy at the imagined state
            policy = model.action_distribution(hidden[:, :, 0])["action_logits"]  # (B, nb, A)
        from_states = beam_state[:, :, None].expand(B, nb, A, -1).reshape(B, nb * A, -1)
        if dynamics is None:
            dyn = model.dynamics(hidden[:, :, per_beam - A :].reshape(B, nb * A, -1))
            r_hat = imagined_reward(model, dyn, reward_threshold)  # (B, nb * A)
            s_hat = model.predicted_next_states(dyn)  # (B, nb * A, S)
        else:
            nxt, rew = dynamics(from_states.numpy(), acts.reshape(B, nb * A).numpy())
            s_hat = torch.as_tensor(nxt).to(beam_state.dtype)  # (B, nb * A, S)
            r_hat = torch.as_tensor(rew, dtype=torch.float32)  # (B, nb * A)
        if trace is not None:
            trace.append(
                {
                    "depth": depth,
                    "states": from_states.numpy(),
                    "actions": acts.reshape(B, nb * A).numpy(),
                    "reward": r_hat.numpy(),
                    "next_state": s_hat.numpy(),
                }
            )
        score = beam_score.repeat_interleave(A, 1) + r_hat  # (B, nb * A)
        if depth > 0 and ties == "index":  # beam-major, actions by index: the reference's layout
            policy_rank = torch.arange(nb * A).expand(B, nb * A)
        else:  # depth 0 (one beam): the sampled or argmax order; `policy`: interleaved over beams
            keys = policy
            if depth == 0 and order == "sample":  # Gumbel-max: argsort of logits + Gumbel noise
                u = torch.rand(policy.shape, generator=generator).clamp_(1e-20, 1.0)  # is a
                keys = policy - torch.log(-torch.log(u))  # permutation drawn from the policy
            rank = torch.argsort(torch.argsort(-keys, dim=2, stable=True), dim=2)  # (B, nb, A)
            policy_rank = (rank * nb + torch.arange(nb)[None, :, None]).view(B, nb * A)
        first = (
            acts.reshape(B, nb * A) if beam_first is None else beam_first.repeat_interleave(A, 1)
        )
        keep = min(beams, nb * A)
        idx = _rank_candidates(score, policy_rank, keep)  # (B, keep) candidate = beam * A + action
        beam_first, beam_score = first.gather(1, idx), score.gather(1, idx)
        if depth == horizon - 1:
            break
        # the kept candidates' paths: their beam's path + [T_j] + their own query-action token
        j, a = idx // A, idx % A  # (B, keep)
        tree.select(j, (per_beam - A) + a)
        prev_state = beam_state[b_idx, j]  # (B, keep, S)
        next_state = s_hat[b_idx, idx]  # (B, keep, S)
        beam_T = model.embed_transitions(
            states=next_state,
            prev_states=prev_state,
            prev_actions=a,
            prev_rewards=r_hat[b_idx, idx],
            prev_dones=torch.zeros(B, keep, dtype=torch.bool),
            has_prev=torch.ones(B, keep, dtype=torch.bool),
        )  # (B, keep, D)
        beam_state, nb = next_state, keep
    return beam_first[:, 0], beam_score[:, 0]


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
    engine: str = "auto",
) -> torch.Tensor:
    """(B, A) the candidate action with the highest predicted reward (policy mean + samples);
    ``engine`` as ``beam_search``'s."""
    B, A = mean.shape
    z = torch.as_tensor(rng.standard_normal((B, samples - 1, A)), dtype=mean.dtype)
    cands = torch.cat(
        [mean[:, None], mean[:, None] + log_std.exp()[:, None] * z], dim=1
    )  # (B, n, A)
    cands = cands.clamp(low, high)
    q = model.embed_query_actions(states[:, None].expand(B, samples, -1), cands)  # (B, n, D)
    tree = make_tree(model, context, beams=1, group=samples, path=0, engine=engine)
    hidden = tree.forward(  # one group of ``samples`` tokens, each seeing the context and itself
        q, torch.zeros(samples, dtype=torch.long), torch.ones(samples, dtype=torch.bool), 0
    )
    r_hat = model.dynamics(hidden)["reward_pred"]  # (B, n)
    best = r_hat.argmax(1)  # (B,)
    return cands[torch.arange(B), best]
