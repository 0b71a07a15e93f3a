"""DICP planning cost at each env's full test set: a planned step against a model-free step, and the
projected wall time of the paper's planned evaluation.

    python benchmarks/bench_planning.py [--envs darkroom dark-key-to-door] [--repeats 2]
        [--threads 2] [--json results/eval/bench_planning.json]

For each env: a randomly initialised paper-size DICP model (speed does not depend on the weights),
every test task of split 0 in one batch (as ``lhf evaluate`` runs them), a context already holding
K transitions of random tokens, in both context modes (``window``: window-trained models, the
default; ``cache``: band-trained models).  Timed, best of ``--repeats``:

- a model-free step: the step's two new tokens appended to the context and the action head;
- a planned step: the same plus ``beam_search`` (10 beams, every action expanded) at depth 1 and at
  the env's plan depth; a step's cost is taken as linear in its depth between the two.

The projection of the paper's evaluation (100 episodes of H steps, planning once the context holds
K transitions, each plan cut at the steps left in the episode) sums those costs over the steps;
environment stepping is not included (it is ~1 % of a model-free step here).
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from lhf_hf.configs import TrainConfig
from lhf_hf.envs import get_spec, task_split
from lhf_hf.evaluation import Context
from lhf_hf.evaluation.planning import beam_search
from lhf_hf.modeling import ICRLModel
from lhf_hf.training import model_config_for


def _model(env: str) -> ICRLModel:
    cfg = model_config_for(get_spec(env), TrainConfig(dataset="-", objective="dicp", out="-"), True)
    torch.manual_seed(0)
    return ICRLModel(cfg).eval()


def _best(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


@torch.no_grad()
def measure(env: str, mode: str, repeats: int) -> dict:
    spec = get_spec(env)
    model = _model(env)
    c = model.config
    B = len(task_split(env, 0)[1])
    D = c.hidden_size
    g = torch.Generator().manual_seed(0)
    ctx = Context(model, mode=mode)
    ctx.append(torch.randn(B, 1, D, generator=g))
    for _ in range(c.context_length - 1):  # the context holds K transitions
        ctx.append(torch.randn(B, 2, D, generator=g), [True, False])
    states = torch.randint(0, c.state_bins, (B, c.state_dim), generator=g)
    step = torch.randn(B, 2, D, generator=g)

    def free():
        # appending moves the window on; its cost does not depend on what is in it
        h = ctx.append(step, [True, False])[:, -1:]
        return model.action_distribution(h)["action_logits"][:, 0]

    logits = free()
    t_free = _best(free, repeats)
    t_plan = {}
    for depth in sorted({1, c.plan_horizon}):
        t_plan[depth] = _best(
            lambda d=depth: beam_search(model, ctx, states, logits, d, c.plan_beams), repeats
        )
    d_max = c.plan_horizon
    slope = (t_plan[d_max] - t_plan[1]) / max(d_max - 1, 1)

    def plan_cost(depth: int) -> float:
        return t_plan[1] + slope * (depth - 1)

    # the paper's evaluation: 100 episodes of H steps; planning once the context holds K transitions
    H, K, total, planned = spec.horizon, c.context_length, 0.0, 0
    for s in range(100 * H):
        total += t_free
        if s + 1 >= K:
            total += plan_cost(min(d_max, H - s % H))
            planned += 1
    return {
        "tasks": B,
        "context_transitions": K,
        "plan_depth": d_max,
        "model_free_step_s": t_free,
        "planned_step_s_depth_1": t_plan[1] + t_free,
        f"planned_step_s_depth_{d_max}": t_plan[d_max] + t_free,
        "ratio_at_full_depth": (t_plan[d_max] + t_free) / t_free,
        "target_ratio": 2 * d_max,
        "projected_eval_100_episodes_min": total / 60,
        "projected_model_free_eval_min": 100 * H * t_free / 60,
        "planned_steps": planned,
    }


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--envs", nargs="+", default=["darkroom", "dark-key-to-door"])
    p.add_argument("--modes", nargs="+", default=["window", "cache"])
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--json", default=None)
    args = p.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    from lhf_hf.collection.backend_verdict import cpu_model

    out = {"cpu": cpu_model(), "torch_threads": torch.get_num_threads(), "envs": {}}
    for env in args.envs:
        out["envs"][env] = {}
        for mode in args.modes:
            row = measure(env, mode, args.repeats)
            out["envs"][env][mode] = row
            print(env, mode, json.dumps(row), flush=True)
    if args.json:
        from lhf_hf.utils.io import write_json_atomic

        write_json_atomic(out, args.json)


if __name__ == "__main__":
    main()
