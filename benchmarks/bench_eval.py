"""In-context evaluation speed: sliding-window KV cache vs full recompute, and DICP planning cost.

    python benchmarks/bench_eval.py [--episodes 12] [--repeats 3] [--model CKPT_DIR] [--json OUT]

Targets (issue "evaluation", docs/design.md 9), darkroom, paper preset, the 8 test tasks of split 0:
- rollout env-steps/s with the sliding-window KV cache vs the same function recomputed every step
  (``--context recompute``: the receptive field, num_hidden_layers x (K - 1) + 1 tokens, with a
  banded mask): >= 10x, identical actions;
- a DICP planning step (beam search, 10 beams, horizon 8) vs a model-free step: <= 2 x horizon
  (issue 22), in both context modes (``cache``: band-trained models; ``window``: window-trained).
Also timed: the cache through HF's own ``LlamaModel.forward`` (``engine="hf"``) instead of the lean
decoder (``lhf_hf/evaluation/decode.py``), and the reference code's protocol (``window``: the last K transitions re-encoded from scratch,
a different function for deeper models).  All modes consume the same random stream; the script
reports whether they took identical actions and, with the contexts fed the same tokens, how far their
policies are apart (total variation).
Without --model, randomly initialised paper-preset models are used (speed does not depend on the
weights).
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from lhf_hf.configs import TrainConfig
from lhf_hf.envs import get_spec, task_split
from lhf_hf.evaluation import Context, make_task_batch, rollout
from lhf_hf.modeling import ICRLModel
from lhf_hf.training import model_config_for

ENV = "darkroom"  # set from --env


def paper_model(objective: str, seed: int = 0) -> ICRLModel:
    cfg = model_config_for(
        get_spec(ENV), TrainConfig(dataset="-", objective=objective, out="-"), True
    )
    torch.manual_seed(seed)
    return ICRLModel(cfg).eval()


def run(model, episodes: int, context: str, plan: bool = False, engine: str = "auto"):
    _, test = task_split(ENV, 0)
    return rollout(
        model,
        make_task_batch(ENV, test, 0, 0),
        episodes,
        seed=1,
        plan=plan,
        context=context,
        progress=False,
        record_actions=True,
        engine=engine,
    )


# (name, context mode, engine): the cache with the lean decoder, the cache through HF's own forward,
# the exact recompute, the reference protocol
VARIANTS = [
    ("cache", "cache", "auto"),
    ("cache_hf_forward", "cache", "hf"),
    ("recompute", "recompute", "auto"),
    ("window", "window", "auto"),
]


def compare_contexts(model, episodes: int, repeats: int) -> dict:
    """Best-of-``repeats`` wall time of each variant (alternating, so machine load hits all)."""
    walls = {name: [] for name, _, _ in VARIANTS}
    actions = {}
    for _ in range(repeats):
        for name, mode, engine in VARIANTS:
            r = run(model, episodes, mode, engine=engine)
            walls[name].append(r.wall_s)
            actions[name] = r.actions
            steps = r.env_steps
    best = {k: min(v) for k, v in walls.items()}
    out = {"env_steps": steps, "env_steps_per_s_cache": steps / best["cache"]}
    for name, _, _ in VARIANTS[1:]:
        same = bool(np.array_equal(actions["cache"], actions[name]))
        first_diff = np.argmax(np.any(actions["cache"] != actions[name], axis=0))
        out[name] = {
            "env_steps_per_s": steps / best[name],
            "cache_speedup": best[name] / best["cache"],
            "identical_actions": same,
            "steps_until_first_difference": int(actions["cache"].shape[1] if same else first_diff),
        }
    return out


@torch.no_grad()
def policy_distance(model, steps: int, other: str) -> dict:
    """Feed identical random transition tokens to a cached and an ``other`` context; TV distance."""
    g = torch.Generator().manual_seed(0)
    a, b = Context(model, "cache"), Context(model, other)
    tv = []
    for _ in range(steps):
        e = torch.randn(8, 1, model.config.hidden_size, generator=g)
        pa = torch.softmax(model.action_distribution(a.append(e))["action_logits"][:, -1], -1)
        pb = torch.softmax(model.action_distribution(b.append(e))["action_logits"][:, -1], -1)
        tv.append(0.5 * (pa - pb).abs().sum(-1).max().item())
    K = model.config.context_length
    return {
        "max_tv_before_full": max(tv[:K]),
        "mean_tv_after_full": float(np.mean(tv[K:])),
        "max_tv_after_full": max(tv[K:]),
    }


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--episodes", type=int, default=12)
    p.add_argument("--model", default=None, help="a trained DICP checkpoint (default: random init)")
    p.add_argument("--json", default=None)
    p.add_argument("--env", default="darkroom", help="gridworld env id (all its test tasks)")
    p.add_argument("--skip-planning", action="store_true")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--repeats", type=int, default=3, help="timings per variant; the best is kept")
    args = p.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    global ENV
    ENV = args.env
    out = {
        "env": ENV,
        "episodes": args.episodes,
        "tasks": len(task_split(ENV, 0)[1]),
        "torch_threads": torch.get_num_threads(),
    }
    if args.model:
        from lhf_hf.evaluation import load_model

        ad = dicp = load_model(args.model)
        out["model"] = args.model
        ENV = ad.config.env_id
        out["env"], out["tasks"] = ENV, len(task_split(ENV, 0)[1])
        args.skip_planning |= ad.config.objective != "dicp"
    else:
        ad, dicp = paper_model("ad"), paper_model("dicp")
    # 1. cache vs recompute vs the window protocol, AD (one token per step) and DICP (two)
    out["cache"] = compare_contexts(ad, args.episodes, args.repeats)
    for other in ("recompute", "window"):
        out["cache"][other].update(policy_distance(ad, 3 * ad.config.context_length, other))
    if ad is not dicp:
        out["cache_dicp"] = compare_contexts(dicp, args.episodes, args.repeats)
        print(json.dumps(out["cache_dicp"], indent=1))
    print(json.dumps(out["cache"], indent=1))
    if args.skip_planning:
        if args.json:
            from lhf_hf.utils.io import write_json_atomic

            write_json_atomic(out, args.json)
        return
    # 2. planning vs model-free (DICP), timed over the steps where the context is full, in both
    # context modes (cache: band-trained models; window: window-trained ones, the default)
    K, H = dicp.config.context_length, get_spec(ENV).horizon
    warm = (K + H - 1) // H  # episodes until the context is full
    n = warm + 3
    out["planning"] = {"beams": dicp.config.plan_beams, "horizon": dicp.config.plan_horizon}
    for mode in ("cache", "window"):
        t_free = min(run(dicp, n, mode).wall_s for _ in range(args.repeats))
        planned = [run(dicp, n, mode, plan=True) for _ in range(args.repeats)]
        t_base = min(run(dicp, warm, mode).wall_s for _ in range(args.repeats))  # before planning
        per_free = (t_free - t_base) / ((n - warm) * H)
        per_plan = (min(r.wall_s for r in planned) - t_base) / ((n - warm) * H)
        out["planning"][mode] = {
            "model_free_step_ms": 1e3 * per_free,
            "planning_step_ms": 1e3 * per_plan,
            "ratio": per_plan / per_free,
            "planned_steps": planned[0].planned_steps,
        }
    print(json.dumps(out["planning"], indent=1))
    if args.json:
        from lhf_hf.utils.io import write_json_atomic

        write_json_atomic(out, args.json)


if __name__ == "__main__":
    main()
