"""In-context rollouts (paper Algorithm 2, "Test"; docs/design.md 7).

All tasks of a batch run in lockstep from an empty context; actions are sampled from the model's
policy (or chosen by the DICP planner once the context is full); the context slides over the last K
transitions.  One token per environment step is appended (DICP: the query-action token of the step
just taken, then the new transition token), so a rollout costs one small backbone call per step with
the KV cache.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch
from tqdm.auto import tqdm

from lhf_hf.errors import UserError

from .context import Context
from .planning import beam_search, greedy_search
from .tokens import StepTokens
from .tree import resolve_engine


@dataclass
class RolloutResult:
    """returns / success: (B, E) per task and episode; actions: (B, E * horizon) when recorded."""

    returns: np.ndarray
    success: np.ndarray | None
    actions: np.ndarray | None
    wall_s: float
    env_steps: int
    planned_steps: int  # steps on which the planner ran (for the whole batch)
    planned_actions: int = 0  # task-steps that acted on the plan (fewer with plan_gate)
    # the context's forward: "lean" (decode.py), "hf" (LlamaModel.forward) or "kernel" (that with
    # the C++ attention kernel, window and recompute contexts)
    engine: str = "hf"
    context: str = "cache"  # the context mode that ran ("auto" resolved)
    plan_engine: str | None = None  # the planner's tree engine (tree.py), None without planning


def _tensor(x, dtype=None) -> torch.Tensor:
    t = torch.as_tensor(np.asarray(x))
    return t if dtype is None else t.to(dtype)


def sample_actions(dist: dict, rng: np.random.Generator, low=-1.0, high=1.0) -> np.ndarray:
    """Sample from the policy with the rollout's own uniform stream (inverse CDF), so that two
    rollouts with the same seed and (numerically) the same policy take the same actions."""
    if "action_logits" in dist:
        logits = dist["action_logits"][:, -1].double().numpy()  # (B, A)
        probs = np.exp(logits - logits.max(1, keepdims=True))
        probs /= probs.sum(1, keepdims=True)  # softmax
        u = rng.random(len(probs))[:, None]
        return np.minimum((np.cumsum(probs, 1) < u).sum(1), probs.shape[1] - 1)
    mean = dist["action_mean"][:, -1].double().numpy()
    std = np.exp(dist["action_log_std"][:, -1].double().numpy())
    return np.clip(mean + std * rng.standard_normal(mean.shape), low, high).astype(np.float32)


@torch.no_grad()
def rollout(
    model,
    tasks,
    episodes: int,
    seed: int = 0,
    plan: bool = False,
    context: str = "auto",
    progress: bool = True,
    record_actions: bool = False,
    engine: str = "auto",
    plan_dynamics: str = "model",
    plan_order: str = "sample",
    plan_ties: str = "index",
    plan_gate: str = "always",
    plan_engine: str = "auto",
    plan_reward_threshold: float | None = None,
) -> RolloutResult:
    """Run ``episodes`` episodes of every task of ``tasks`` (a task batch) in context.

    ``context``: how the sliding context is computed (``Context`` modes; ``auto``: the model's
    training semantics, ``context.trained_mode``); ``engine``: the cached
    step's forward, ``auto`` (the lean exact decoder where the model allows it), ``lean`` or ``hf``;
    ``plan_dynamics``: ``model`` (the learned heads) or ``oracle`` (the environment's own dynamics
    inside the planner, a diagnostic; gridworlds without a key); ``plan_order``: the beam search's
    depth-0 tie order, ``sample`` (drawn from the policy on this rollout's seeded stream, the
    reference's) or ``argmax``; ``plan_ties``: its tie order below depth 0, ``index`` (the
    reference's) or ``policy`` (ours; ``beam_search``); ``plan_gate``: ``always`` (the reference: plan on every step once the
    context is full) or ``reward_seen`` (plan only for tasks whose context holds a nonzero reward;
    the others act on a policy sample: without an observed reward a predicted one can only be a
    false positive of the learned head, which the search would follow; docs/evaluation.md);
    ``plan_engine``: the planner's backbone over its tree (``tree.py``), ``auto`` (the C++ tree
    attention kernel where the model allows it), ``kernel`` or ``torch`` (the reference);
    ``plan_reward_threshold``: the beam search imagines a nonzero reward only at this probability
    or more (``planning.imagined_reward``; None: the reference's most likely class)."""
    c = model.config
    model.eval()
    dicp = c.objective == "dicp"
    if plan and not dicp:
        raise UserError(
            f"planning needs the dynamics heads of a DICP model; this model's objective is {c.objective!r}"
        )
    if plan_dynamics not in ("model", "oracle"):
        raise UserError(f"plan_dynamics must be 'model' or 'oracle', got {plan_dynamics!r}")
    if plan_gate not in ("always", "reward_seen"):
        raise UserError(f"plan_gate must be 'always' or 'reward_seen', got {plan_gate!r}")
    if plan and plan_gate != "always" and not c.discrete_actions:
        raise UserError(
            "plan_gate='reward_seen' gates the beam search of discrete-action envs; continuous "
            "actions plan with the greedy search, whose dense rewards need no gate"
        )
    plan_engine = resolve_engine(model, plan_engine) if plan else None
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    plan_gen = torch.Generator().manual_seed(seed)  # the planner's depth-0 orders
    ctx = Context(model, mode=context, engine=engine)
    tokens = StepTokens(model)
    # read once: a transformers config attribute costs ~2 us per access
    K, discrete = c.context_length, c.discrete_actions
    if plan and plan_ties != "index" and not discrete:
        raise UserError(
            "plan_ties orders the beam search of discrete actions; this model's actions are "
            "continuous (greedy search, which has no ties to order)"
        )
    if plan and plan_reward_threshold is not None and not discrete:
        raise UserError(
            "a planning reward threshold applies to the beam search of discrete actions; this "
            "model's actions are continuous (greedy search over a regressed reward)"
        )
    horizon, beams = c.plan_horizon, c.plan_beams
    H = tasks.horizon
    returns, success, taken = [], [], []
    prev = None  # (state, action, reward, done) of the last step, numpy
    seen = None  # (B, K) rewards of the last K transitions, for plan_gate="reward_seen"
    steps = planned = planned_actions = 0
    t0 = time.perf_counter()
    bar = tqdm(total=episodes, unit="episode", disable=not progress, desc="evaluate", leave=False)
    for _ in range(episodes):
        state = tasks.reset()
        B = len(state)
        ep_return = np.zeros(B, np.float64)
        ep_success = np.zeros(B, bool)
        for t in range(H):
            s = _tensor(state)[:, None]  # (B, 1, S)
            tok = tokens.transition(state, prev)  # (B, 1, D)
            is_query = None
            if dicp and prev is not None:  # the query-action token of the step just taken
                q = tokens.query(prev[0], prev[1])  # (B, 1, D)
                tok = torch.cat([q, tok], dim=1)  # (B, 2, D)
                is_query = [True, False]
            hidden = ctx.append(tok, is_query)[:, -1:]  # (B, 1, D)
            dist = model.action_distribution(hidden)
            full = steps + 1 >= K  # the context holds K transitions
            if plan and full and discrete:
                action, _ = beam_search(
                    model,
                    ctx,
                    s[:, 0],
                    dist["action_logits"][:, 0],
                    min(horizon, H - t),
                    beams,
                    dynamics=tasks.imagine if plan_dynamics == "oracle" else None,
                    order=plan_order,
                    ties=plan_ties,
                    generator=plan_gen,
                    engine=plan_engine,
                    reward_threshold=plan_reward_threshold,
                )
                action = action.numpy()
                if plan_gate == "reward_seen":
                    # tasks with no reward in the context act on a policy sample instead (the
                    # search still runs for the whole batch: the context is shared)
                    sampled = sample_actions(dist, rng)
                    gate = (seen != 0).any(1)  # (B,)
                    action = np.where(gate, action, sampled)
                    planned_actions += int(gate.sum())
                else:
                    planned_actions += len(action)
                planned += 1
            elif plan and full and t >= H // 2:  # continuous: second half of each episode (ref)
                action = greedy_search(
                    model,
                    ctx,
                    s[:, 0],
                    dist["action_mean"][:, 0],
                    dist["action_log_std"][:, 0],
                    c.plan_samples,
                    rng,
                    engine=plan_engine,
                ).numpy()
                planned += 1
                planned_actions += len(action)
            else:
                action = sample_actions(dist, rng)
            nxt, reward, done, succ = tasks.step(action)
            ep_return += reward
            if succ is not None:
                ep_success |= succ
            if record_actions:
                taken.append(np.asarray(action))
            if plan_gate == "reward_seen":
                seen = np.zeros((len(state), K), np.float32) if seen is None else seen
                seen[:, steps % K] = reward  # a ring over the last K transitions
            prev = (state, action, reward, done)
            state = nxt
            steps += 1
        returns.append(ep_return)
        success.append(ep_success)
        bar.update(1)
        bar.set_postfix(mean_return=f"{ep_return.mean():.2f}")
    bar.close()
    return RolloutResult(
        returns=np.stack(returns, 1),
        success=np.stack(success, 1) if tasks.has_success else None,
        actions=np.stack(taken, 1) if record_actions else None,
        wall_s=time.perf_counter() - t0,
        env_steps=steps * len(state),
        planned_steps=planned,
        planned_actions=planned_actions,
        engine=ctx.engine,
        context=ctx.mode,
        plan_engine=plan_engine,
    )
