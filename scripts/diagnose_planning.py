"""Why does DICP planning help or hurt?  Returns without planning, with the learned dynamics and with
the environment's true dynamics inside the same planner, and the accuracy of the learned reward and
next-state heads at depth 0, on the tokens exactly as the planner builds them.

    python scripts/diagnose_planning.py --model runs/dicp-cpu [--episodes 40] [--seeds 0 1]
        [--json results/planning/diagnose.json] [--parts runs heads depth false-positives]

Darkroom-family gridworlds without a key (the true dynamics need the goal alone).  The validation
goals of the model's split (``--tasks test --report-on-test``: its test goals, to report a choice
already made; a diagnosis that chooses a setting looks at validation goals only); each seed is a separate rollout.  Head accuracy is measured during the
model-free rollout, at every step with a full context: for each of the 5 actions from the current
state, the reward head's prediction (thresholded at 0.5) and the next-state head's prediction
against the true ones, split by whether the true reward is 1 (the goal cell) or 0, and by episode.
``depth``: the same for every candidate of one beam search, by depth.  ``false-positives``: the
rate of predicted rewards the true dynamics do not give, with and without a rewarded step in the
window, and which moves they are (distance of the move's start and end cells to the goal).
``data``: how often the source agents leave the goal in the model's training data.  With
``--json`` the parts measured are added to (or replace those in) an earlier diagnosis of the model.
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
from lhf_hf.evaluation.planning import beam_search
from lhf_hf.evaluation.rollout import rollout, sample_actions
from lhf_hf.evaluation.seen import TUNING_PARTS, check_unseen, tuning_tasks
from lhf_hf.evaluation.task_batch import make_task_batch
from lhf_hf.evaluation.tokens import StepTokens
from lhf_hf.modeling import load_model


def _full_context_steps(model, batch, episodes: int, seed: int):
    """A model-free rollout (the policy's own samples, the rollout's token stream); yields
    ``(episode, t, context, states (B, S), policy logits (B, A))`` at every step whose context
    holds K transitions, i.e. where the planner would plan, and the rewards (B,) of every real step
    before it."""
    c = model.config
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    ctx, tokens = Context(model, mode="auto"), StepTokens(model)
    prev, steps, rewards = None, 0, []
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
                yield ep, t, ctx, state, dist["action_logits"][:, 0], rewards
            action = sample_actions(dist, rng)
            nxt_state, reward, done, _ = batch.step(action)
            prev = (state, action, reward, done)
            rewards.append(np.asarray(reward))
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
    for ep, _, ctx, state, logits, _ in _full_context_steps(model, batch, episodes, seed):
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
    for _, t, ctx, state, logits, _ in _full_context_steps(model, batch, episodes, seed):
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


@torch.no_grad()
def false_positives(model, batch, episodes: int, seed: int) -> dict:
    """Where the reward head predicts a reward that the true dynamics do not give (depth 0, at every
    full-context step of a model-free rollout): split by whether the window holds a rewarded step,
    and each false positive by its kind: the move's start and end cells' distance to the goal."""
    c = model.config
    gen = torch.Generator().manual_seed(seed)
    counts = {"reward in window": [0, 0], "no reward in window": [0, 0]}  # [false pos., non-goal]
    kinds: dict[str, int] = {}
    goal = batch.core._coords[batch.core._goal]  # (B, S) the goal cell of each task
    for _, _, ctx, state, logits, rewards in _full_context_steps(model, batch, episodes, seed):
        seen = (np.stack(rewards[-(c.context_length - 1) :]) > 0).any(0)  # (B,) in the window
        (d0,) = _imagined(model, ctx, state, logits, 1, gen)
        nxt, rew = batch.imagine(np.rint(d0["states"]), d0["actions"])
        fp = (d0["reward"] >= 0.5) & (rew < 0.5)  # (B, A)
        for b in range(len(state)):
            key = "reward in window" if seen[b] else "no reward in window"
            counts[key][0] += int(fp[b].sum())
            counts[key][1] += int((rew[b] < 0.5).sum())
            for i in np.where(fp[b])[0]:
                d_from = int(np.abs(d0["states"][b, i] - goal[b]).sum())
                d_to = int(np.abs(nxt[b, i] - goal[b]).sum())
                kind = f"from {d_from} to {d_to} cells from the goal"
                kinds[kind] = kinds.get(kind, 0) + 1
    total = sum(kinds.values())
    return {
        "rate": {k: round(f / max(n, 1), 4) for k, (f, n) in counts.items()},
        "non_goal_candidates": {k: n for k, (_, n) in counts.items()},
        "false_positives": total,
        "kinds": {
            k: round(v / max(total, 1), 3)
            for k, v in sorted(kinds.items(), key=lambda kv: -kv[1])[:6]
        },
    }


def goal_departures(dataset: str) -> dict:
    """How often the source agents leave the goal in the training data: the steps that start on the
    goal (the step before was rewarded, same episode) and of those, the ones that earn nothing.  The
    reward head sees (on the goal, leave, 0) only this often against (on the goal, stay, 1)."""
    import pyarrow.parquet as pq

    n = on_goal = leave = 0
    cols = ["next.reward", "next.done", "history_index"]
    for f in sorted(Path(dataset, "data").glob("**/*.parquet")):
        t = pq.read_table(f, columns=cols)
        r, d, h = (t[c].to_numpy() for c in cols)
        same = np.r_[False, (h[1:] == h[:-1]) & ~d[:-1]]  # the step before is in the same episode
        starts_on_goal = np.r_[False, r[:-1] > 0] & same
        n, on_goal = n + len(r), on_goal + int(starts_on_goal.sum())
        leave += int((starts_on_goal & (r == 0)).sum())
    return {
        "steps": n,
        "start_on_goal": round(on_goal / max(n, 1), 4),
        "leave_of_those": round(leave / max(on_goal, 1), 4),
    }


PARTS = ("runs", "heads", "depth", "false-positives", "data")


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--model", required=True)
    p.add_argument("--episodes", type=int, default=40)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--split-seed", type=int, default=None,
                   help="default: the split of the model's training dataset (as lhf evaluate)")  # fmt: skip
    p.add_argument("--json", default=None)
    p.add_argument("--tasks", default="validation", choices=TUNING_PARTS,
                   help="the goals measured: validation (a model trained on `lhf collect --tasks "
                   "fit` data), or test with --report-on-test")
    p.add_argument("--report-on-test", action="store_true",
                   help="allow --tasks test: reporting a choice already made, not making one")
    p.add_argument("--parts", nargs="+", default=list(PARTS), choices=PARTS,
                   help="what to measure (default: all)")  # fmt: skip
    args = p.parse_args()
    try:
        run(args)
    except (ValueError, FileNotFoundError, json.JSONDecodeError) as exc:
        raise SystemExit(f"error: {exc}") from None


def run(args) -> None:
    if not Path(args.model, "config.json").is_file():
        raise FileNotFoundError(f"{args.model} is not a model folder (no config.json)")
    model = load_model(args.model)
    env = model.config.env_id
    train_cfg = Path(args.model, "train_config.json")
    provenance = json.loads(train_cfg.read_text()) if train_cfg.is_file() else {}
    split_seed = args.split_seed
    if split_seed is None:  # the model's own split, as lhf evaluate (a checkpoint: its config's)
        split_seed = model.config.split_seed
        if split_seed is None:
            split_seed = (provenance.get("dataset") or {}).get("split_seed")
        if split_seed is None:
            raise ValueError(f"{args.model} does not record its split seed: pass --split-seed")
        split_seed = int(split_seed)
    args.split_seed = split_seed
    tasks = tuning_tasks(env, args.tasks, split_seed, args.report_on_test)
    check_unseen(get_spec(env), model.config, tasks, split_seed, False, args.model)  # as evaluate
    optimal = float(get_spec(env).optimal_returns()[tasks].mean())
    model_id = str(Path(args.model).resolve())
    needs_planner = [p for p in args.parts if p != "data"]
    if needs_planner and model.config.objective != "dicp":
        raise ValueError(
            f"parts {needs_planner} need a DICP model (its planner and dynamics heads); "
            f"{args.model} is {model.config.objective!r}"
        )
    if needs_planner:  # the true dynamics: refused up front for envs that cannot give them
        probe = make_task_batch(env, tasks[:1], split_seed, 0)
        probe.imagine(probe.reset()[:, None], np.zeros((1, 1), np.int64))
    out = {"model": args.model, "env_id": env, "split_seed": split_seed, "tasks": tasks,
           "optimal": optimal}  # fmt: skip
    if args.json and Path(args.json).exists():  # add the parts asked for to an earlier diagnosis
        earlier = json.loads(Path(args.json).read_text())
        same = str(Path(earlier.get("model", "")).resolve()) == model_id
        if not same or earlier.get("tasks") != tasks:
            raise ValueError(
                f"{args.json} holds a diagnosis of {earlier.get('model')!r} on tasks "
                f"{earlier.get('tasks')}, not of this model on {tasks}: choose another --json"
            )
        out = {**earlier, **out}

    def batch(seed):
        return make_task_batch(env, tasks, args.split_seed, seed)

    if "runs" in args.parts:
        out["runs"] = {}
        for mode, kw in [
            ("no plan", {}),
            ("plan, learned dynamics", {"plan": True}),
            ("plan, true dynamics", {"plan": True, "plan_dynamics": "oracle"}),
        ]:
            per_seed = []
            for seed in args.seeds:
                t0 = time.perf_counter()
                res = rollout(model, batch(seed), args.episodes, seed=seed, progress=False, **kw)
                per_seed.append(
                    {
                        "mean": float(res.returns.mean()),
                        "last10": float(res.returns[:, -10:].mean()),
                        "wall_s": round(time.perf_counter() - t0, 1),
                    }  # fmt: skip
                )
            out["runs"][mode] = per_seed
            print(mode, json.dumps(per_seed))
    for part, key, fn in [
        ("heads", "heads", head_accuracy),
        ("depth", "by_depth", depth_accuracy),
        ("false-positives", "false_positives", false_positives),
    ]:
        if part in args.parts:
            out[key] = {seed: fn(model, batch(seed), args.episodes, seed) for seed in args.seeds}
            print(key, json.dumps(out[key], indent=1))
    if "data" in args.parts:
        dataset = (provenance.get("dataset") or {}).get("path")
        if dataset is None:
            raise FileNotFoundError(f"{args.model} records no training dataset (train_config.json)")
        out["goal_departures"] = {"dataset": dataset, **goal_departures(dataset)}
        print("goal_departures", out["goal_departures"])
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
