"""Why does DICP planning help or hurt?  Returns without planning, with the learned dynamics and with
the environment's true dynamics inside the same planner, and the accuracy of the learned reward and
next-state heads at depth 0, on the tokens exactly as the planner builds them.

    python scripts/diagnose_planning.py --model runs/dicp-cpu [--episodes 40] [--seeds 0 1]
        [--json results/planning/diagnose.json]

Darkroom-family gridworlds without a key (the true dynamics need the goal alone).  The unseen goals
of the model's split; each seed is a separate rollout.  Head accuracy is measured during the
model-free rollout, at every step with a full context: for each of the 5 actions from the current
state, the reward head's prediction (thresholded at 0.5) and the next-state head's prediction
against the true ones, split by whether the true reward is 1 (the goal cell) or 0, and by episode.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from lhf_hf.envs import get_spec
from lhf_hf.evaluation.context import Context
from lhf_hf.evaluation.evaluate import resolve_tasks
from lhf_hf.evaluation.planning import beam_search
from lhf_hf.evaluation.rollout import rollout, sample_actions
from lhf_hf.evaluation.task_batch import make_task_batch
from lhf_hf.evaluation.tokens import StepTokens
from lhf_hf.modeling import load_model


def _full_context_steps(model, batch, episodes: int, seed: int):
    """A model-free rollout (the policy's own samples, the rollout's token stream); yields
    ``(episode, t, context, states (B, S), policy logits (B, A))`` at every step whose context
    holds K transitions, i.e. where the planner would plan."""
    c = model.config
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    ctx, tokens = Context(model, mode="cache"), StepTokens(model)
    prev, steps = None, 0
    for ep in range(episodes):
        state = batch.reset()
        for t in range(batch.horizon):
            tok = tokens.transition(state, prev)
            is_query = None
            if prev is not None:
                tok = torch.cat([tokens.query(prev[0], prev[1]), tok], dim=1)
                is_query = [True, False]
            hidden = ctx.append(tok, is_query)[:, -1:]
            dist = model.action_distribution(hidden)
            if steps + 1 >= c.context_length:
                yield ep, t, ctx, state, dist["action_logits"][:, 0]
            action = sample_actions(dist, rng)
            nxt_state, reward, done, _ = batch.step(action)
            prev = (state, action, reward, done)
            state = nxt_state
            steps += 1


def _imagined(model, ctx, state, logits, horizon: int, gen) -> list[dict]:
    """Every candidate one beam search imagines, depth by depth (``beam_search``'s trace)."""
    trace: list = []
    beam_search(model, ctx, torch.as_tensor(state, dtype=torch.float32), logits, horizon,
                model.config.plan_beams, order="sample", generator=gen, trace=trace)  # fmt: skip
    return trace


@torch.no_grad()
def head_accuracy(model, batch, episodes: int, seed: int) -> dict:
    """Model-free rollout; at every full-context step, the depth-0 predictions vs the truth."""
    gen = torch.Generator().manual_seed(seed)
    rows = []  # (episode, true reward, reward right, next state right)
    for ep, _, ctx, state, logits in _full_context_steps(model, batch, episodes, seed):
        (d0,) = _imagined(model, ctx, state, logits, 1, gen)  # every action from the state
        nxt, rew = batch.imagine(np.rint(d0["states"]), d0["actions"])
        right_r = (d0["reward"] >= 0.5) == (rew >= 0.5)
        right_s = (np.rint(d0["next_state"]) == nxt).all(-1)
        for r, a, b in zip(rew.ravel(), right_r.ravel(), right_s.ravel(), strict=True):
            rows.append((ep, float(r), bool(a), bool(b)))
    arr = np.array(rows, dtype=np.float64)  # (n, 4)
    goal, other = arr[arr[:, 1] >= 0.5], arr[arr[:, 1] < 0.5]

    def acc(x, col):
        return None if len(x) == 0 else round(float(x[:, col].mean()), 4)

    by_episode = {}
    for lo in range(0, episodes, 10):
        part = arr[(arr[:, 0] >= lo) & (arr[:, 0] < lo + 10)]
        g, o = part[part[:, 1] >= 0.5], part[part[:, 1] < 0.5]
        by_episode[f"{lo + 1}-{lo + 10}"] = {
            "reward_acc_goal": acc(g, 2),
            "reward_acc_other": acc(o, 2),
            "next_state_acc_goal": acc(g, 3),
            "next_state_acc_other": acc(o, 3),
            "goal_candidates": len(g),
        }
    return {
        "candidates": len(arr),
        "goal_candidates": len(goal),
        "reward_acc_goal": acc(goal, 2),  # predicted r >= 0.5 where the true reward is 1
        "reward_acc_other": acc(other, 2),  # predicted r < 0.5 where it is 0
        "next_state_acc_goal": acc(goal, 3),
        "next_state_acc_other": acc(other, 3),
        "by_episode": by_episode,
    }


@torch.no_grad()
def depth_accuracy(model, batch, episodes: int, seed: int) -> dict:
    """At every full-context step of a model-free rollout, one beam search as the planner runs it;
    every candidate it imagines, at every depth, against the true reward and next state of the
    same (imagined) state and action: where along the imagined paths do the heads go wrong?"""
    gen = torch.Generator().manual_seed(seed)
    per_depth: dict[int, list] = {}
    for _, t, ctx, state, logits in _full_context_steps(model, batch, episodes, seed):
        horizon = min(model.config.plan_horizon, batch.horizon - t)
        for d in _imagined(model, ctx, state, logits, horizon, gen):
            nxt, rew = batch.imagine(np.rint(d["states"]), d["actions"])
            goal = rew >= 0.5
            per_depth.setdefault(d["depth"], []).append(
                np.stack(
                    [
                        goal.ravel(),
                        ((d["reward"] >= 0.5) == goal).ravel(),
                        (np.rint(d["next_state"]) == nxt).all(-1).ravel(),
                    ],
                    1,
                )  # fmt: skip
            )
    out = {}
    for depth, parts in sorted(per_depth.items()):
        a = np.concatenate(parts).astype(np.float64)  # (n, 3): goal, reward right, state right
        g, o = a[a[:, 0] > 0], a[a[:, 0] == 0]
        out[depth] = {
            "candidates": len(a),
            "reward_acc_goal": None if len(g) == 0 else round(float(g[:, 1].mean()), 4),
            "reward_false_positive": None if len(o) == 0 else round(1 - float(o[:, 1].mean()), 4),
            "next_state_acc": round(float(a[:, 2].mean()), 4),
        }
    return out


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--model", required=True)
    p.add_argument("--episodes", type=int, default=40)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--split-seed", type=int, default=0)
    p.add_argument("--json", default=None)
    args = p.parse_args()
    model = load_model(args.model)
    env = model.config.env_id
    tasks = resolve_tasks(env, "test", args.split_seed)
    optimal = float(get_spec(env).optimal_returns()[tasks].mean())
    out = {"model": args.model, "env_id": env, "tasks": tasks, "optimal": optimal, "runs": {}}
    for mode, kw in [
        ("no plan", {}),
        ("plan, learned dynamics", {"plan": True}),
        ("plan, true dynamics", {"plan": True, "plan_dynamics": "oracle"}),
    ]:
        per_seed = []
        for seed in args.seeds:
            t0 = time.perf_counter()
            res = rollout(model, make_task_batch(env, tasks, args.split_seed, seed),
                          args.episodes, seed=seed, progress=False, **kw)  # fmt: skip
            per_seed.append(
                {
                    "mean": float(res.returns.mean()),
                    "last10": float(res.returns[:, -10:].mean()),
                    "wall_s": round(time.perf_counter() - t0, 1),
                }  # fmt: skip
            )
        out["runs"][mode] = per_seed
        print(mode, json.dumps(per_seed))
    out["heads"] = {
        seed: head_accuracy(
            model, make_task_batch(env, tasks, args.split_seed, seed), args.episodes, seed
        )  # fmt: skip
        for seed in args.seeds
    }
    print(json.dumps(out["heads"], indent=1))
    out["by_depth"] = {
        seed: depth_accuracy(
            model, make_task_batch(env, tasks, args.split_seed, seed), args.episodes, seed
        )  # fmt: skip
        for seed in args.seeds
    }
    print(json.dumps(out["by_depth"], indent=1))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
