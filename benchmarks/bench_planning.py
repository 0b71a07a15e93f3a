"""DICP planning against its FLOP floor: a planned step against a model-free one, before and after
the kernels, and the projected wall time of a planned evaluation.

    python benchmarks/bench_planning.py [--envs darkroom darkroom-permuted] [--rollouts 4]
        [--threads 1 2] [--rounds 3] [--mode window] [--batch N] [--profile] [--json OUT]

For each env: a randomly initialised paper-size DICP model (speed does not depend on the weights),
every test task of split 0 times ``--rollouts`` in one batch (as ``lhf evaluate --rollouts`` runs
them; ``--batch`` sets another size), a context already holding K transitions of random tokens in
``--mode`` (``window``: window-trained models, the presets' default; ``cache``: band-trained).
Timed in one process, ``--rounds`` rounds in an order rotated each round, medians:

- ``free_hf`` / ``free_kernel``: a model-free step (its two new tokens appended to the context, the
  action head) with the model's own attention (context engine ``hf``, before) and with the C++
  attention kernel (engine ``auto``, after; for ``window`` the whole window is re-encoded);
- ``search_torch`` / ``search_kernel``: ``beam_search`` (10 beams, every action expanded) at the
  env's plan depth (and at depth 1, for the projection) with each tree engine
  (``lhf_hf/evaluation/tree.py``); a planned step is a model-free step plus a search;
- ``sgemm``: the float32 matmul rate at the same thread count (``bench_train_floor.sgemm_gflops``),
  per wall second and per CPU second of the process.

Every call is timed in wall time and in the process's CPU time: on a shared, loaded machine the
wall time also counts the time other processes hold the cores, so ``x_floor_cpu`` (CPU seconds
against the floor at the sgemm rate per CPU second) is the steadier measure of efficiency;
``x_floor`` (wall against wall) is the one a user waits for.

FLOPs: the matmuls (projections, MLP, embeddings and heads) as torch's ``FlopCounterMode`` counts
them on the torch paths (an analytic count is checked against it), plus the attention's, counted
analytically (``FlopCounterMode`` does not count CPU SDPA or the kernels): 4 d per (query, key,
head, layer).  ``dense``: the pairs the torch tree engine computes (every token against the
context and the whole tree so far); ``floor``: the pairs the reference's semantics need (each
imagined token against its window of the context and its own path; the causal pairs of the window
a model-free step re-encodes).  The floor is the matmuls plus the floor's attention at the sgemm
rate: ``x_floor`` = measured / floor.

The projection (``lhf evaluate --plan`` at the cpu preset: 100 episodes of H steps, planning once
the context holds K transitions, each plan cut at the steps left in the episode) sums a model-free
step per env-step and a search per planned step (``projected_eval_min``: the measured wall times;
``_idle``: the CPU times divided by the threads, what an idle machine would take without waiting),
the search's cost interpolated in its imagined
tokens between depth 1 and full depth (per token a search costs the same at every depth with the
kernel; the torch engine's per-token cost grows with the tree, so its projection is a lower bound).
Environment stepping is not included (~1 % of a model-free step).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import torch
from torch.profiler import profile
from torch.utils.flop_counter import FlopCounterMode

from lhf_hf.collection.backend_verdict import cpu_model
from lhf_hf.configs import TrainConfig
from lhf_hf.envs import get_spec, task_split
from lhf_hf.evaluation import Context
from lhf_hf.evaluation.planning import beam_search, depth_tokens
from lhf_hf.evaluation.tree import _context_window
from lhf_hf.modeling import ICRLModel, tree_attention
from lhf_hf.training import model_config_for
from lhf_hf.utils.io import write_json_atomic


def _model(env: str) -> ICRLModel:
    cfg = model_config_for(get_spec(env), TrainConfig(dataset="-", objective="dicp", out="-"), True)
    torch.manual_seed(0)
    return ICRLModel(cfg).eval()


# ---------------------------------------------------------------------------- FLOP counts
def token_flops(c) -> int:
    """Matmul FLOPs of one token through the backbone (the reference's projections and MLP)."""
    D, H, Hkv = c.hidden_size, c.num_attention_heads, c.num_key_value_heads
    dh = D // H
    inter = c.intermediate_size
    return 2 * c.num_hidden_layers * (D * (H + 2 * Hkv) * dh + H * dh * D + 3 * D * inter)


def attention_flops(c, pairs: int) -> int:
    """FLOPs of ``pairs`` (query, key) pairs in every head and layer: q.k and p.v, d each."""
    dh = c.hidden_size // c.num_attention_heads
    return 4 * dh * c.num_attention_heads * c.num_hidden_layers * pairs


def search_counts(model, L0: int, window: int, horizon: int, ties: str = "index") -> dict:
    """Per task: the search's imagined tokens, their matmul FLOPs (backbone, embeddings, heads)
    and its (query, key) pairs, dense (the torch engine) and visible (the floor)."""
    c = model.config
    A, beams, D = c.action_dim, c.plan_beams, c.hidden_size
    F_q = model.embed_query_action.in_features
    F_t = model.embed_transition.in_features
    heads_q = model.reward_head.out_features + 1 + model.next_state_head.out_features
    tokens = dense = visible = flops = 0
    nb, n_tree = 1, 0
    for depth in range(horizon):
        per_beam = A + (depth > 0)
        n = nb * per_beam
        offsets = torch.full((per_beam,), 2 * depth)
        is_query = torch.ones(per_beam, dtype=torch.bool)
        if depth:
            offsets[0], is_query[0] = 2 * depth - 1, False
        lo = _context_window(L0, window, offsets, is_query)  # (per_beam,)
        plen = max(2 * depth - 1, 0)
        seen_new = torch.clamp(torch.arange(per_beam), max=int(depth > 0)) + 1  # shared + itself
        visible += nb * int(((L0 - lo) + plen + seen_new).sum())
        dense += n * (L0 + n_tree + n)
        flops += n * token_flops(c) + nb * A * 2 * D * (F_q + heads_q)  # Q tokens: embed, heads
        if depth and ties == "policy":
            flops += nb * 2 * D * A  # the policy at each beam's T token orders its ties
        keep = min(beams, nb * A)
        if depth < horizon - 1:
            flops += keep * 2 * F_t * D  # the kept candidates' T tokens
        tokens += n
        n_tree += n
        nb = keep
    assert tokens == sum(depth_tokens(A, horizon, beams))
    return {"tokens": tokens, "matmul_flops": flops, "dense_pairs": dense, "visible_pairs": visible}


def free_counts(model, ctx: Context) -> dict:
    """Per task: a model-free step's matmul FLOPs and its (query, key) pairs."""
    c = model.config
    step = 2 * c.hidden_size * c.action_dim  # the action head
    if ctx.mode == "window":  # the window re-encoded with causal attention
        L = ctx.max_tokens
        return {"matmul_flops": L * token_flops(c) + step, "visible_pairs": L * (L + 1) // 2}
    L = ctx.length  # cache: two new tokens against the kept ones
    return {"matmul_flops": 2 * token_flops(c) + step, "visible_pairs": 2 * L + 1}


def counted_matmul_flops(fn) -> int:
    with FlopCounterMode(display=False) as counter:
        fn()
    return counter.get_total_flops()


# ---------------------------------------------------------------------------- timing
def timed(fn) -> tuple[float, float]:
    """(wall seconds, CPU seconds of this process) of one call of ``fn``."""
    w, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w, time.process_time() - c


def sgemm_rates(n: int = 1024, repeats: int = 3) -> tuple[float, float]:
    """The float32 matmul rate at torch's thread count, best of ``repeats``: GFLOP per wall second
    (``bench_train_floor.sgemm_gflops``) and per CPU second of this process."""
    a, b = torch.randn(n, n), torch.randn(n, n)
    torch.mm(a, b)
    w, c = min(timed(lambda: torch.mm(a, b)) for _ in range(repeats))
    return 2 * n**3 / w / 1e9, 2 * n**3 / c / 1e9


class _KernelClock:
    """Wall and CPU time inside the tree attention kernel's calls."""

    def __init__(self):
        self.seconds = self.cpu_seconds = 0.0
        self._forward = tree_attention.forward

    def __enter__(self):
        def timed_forward(*args, **kwargs):
            w, c = time.perf_counter(), time.process_time()
            try:
                return self._forward(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - w
                self.cpu_seconds += time.process_time() - c

        tree_attention.forward = timed_forward
        return self

    def __exit__(self, *exc):
        tree_attention.forward = self._forward


def _top_ops(fn, rows: int = 8) -> list:
    """The ``rows`` torch ops with the most self CPU time in one call of ``fn`` (ms)."""
    with profile() as prof:
        fn()
    events = sorted(prof.key_averages(), key=lambda e: -e.self_cpu_time_total)[:rows]
    return [[e.key, round(e.self_cpu_time_total / 1e3, 2), e.count] for e in events]


@torch.no_grad()
def measure(env: str, mode: str, batch: int | None, rollouts: int, threads: list, rounds: int,
            profile_ops: bool, ties: str = "index") -> dict:  # fmt: skip
    """One env: FLOPs, then per thread count the rounds of timings; ``before``: the model's own
    attention for the context's window (engine hf) and the torch tree engine; ``after``: the
    attention kernel for the window and the kernel tree engine."""
    spec = get_spec(env)
    model = _model(env)
    c = model.config
    tasks = len(task_split(env, 0)[1])
    B = batch or tasks * rollouts
    D, K, d_max = c.hidden_size, c.context_length, c.plan_horizon
    g = torch.Generator().manual_seed(0)
    ctxs = {"hf": Context(model, mode=mode, engine="hf"), "auto": Context(model, mode=mode)}
    first = torch.randn(B, 1, D, generator=g)
    tokens = [torch.randn(B, 2, D, generator=g) for _ in range(K - 1)]
    for ctx in ctxs.values():
        ctx.append(first)
        for tok in tokens:  # the context holds K transitions
            ctx.append(tok, [True, False])
    ctx = ctxs["auto"]
    states = torch.randint(0, c.state_bins, (B, c.state_dim), generator=g)
    step = torch.randn(B, 2, D, generator=g)

    def free(context=ctx):
        # appending moves the window on; its cost does not depend on what is in it
        h = context.append(step, [True, False])[:, -1:]
        return model.action_distribution(h)["action_logits"][:, 0]

    logits = free()
    free(ctxs["hf"])
    _, L0, _ = ctx.snapshot()

    def search(engine, depth=d_max):
        return lambda: beam_search(
            model, ctx, states, logits, depth, c.plan_beams, engine=engine, ties=ties
        )

    # FLOPs per task, the analytic counts checked against FlopCounterMode's
    counts = {d: search_counts(model, L0, ctx.max_tokens, d, ties) for d in sorted({1, d_max})}
    fc = free_counts(model, ctx)
    counted = {
        "search": counted_matmul_flops(search("torch")) / B,
        "model_free": counted_matmul_flops(lambda: free(ctxs["hf"])) / B,
    }
    for name, want in (
        ("search", counts[d_max]["matmul_flops"]),
        ("model_free", fc["matmul_flops"]),
    ):
        if abs(counted[name] - want) > 1e-6 * want:
            raise AssertionError(
                f"{name}: FlopCounterMode {counted[name]:.6g} != analytic {want:.6g}"
            )
    search_floor = counts[d_max]["matmul_flops"] + attention_flops(
        c, counts[d_max]["visible_pairs"]
    )
    free_floor = fc["matmul_flops"] + attention_flops(c, fc["visible_pairs"])
    row = {
        "tasks": tasks,
        "batch": B,
        "context_mode": mode,
        "context_transitions": K,
        "context_tokens": L0,
        "plan_depth": d_max,
        "tree_tokens_per_task": counts[d_max]["tokens"],
        "per_task": {
            "model_free_mflop_floor": free_floor / 1e6,
            "search_mflop_floor": search_floor / 1e6,
            "search_mflop_dense": (
                counts[d_max]["matmul_flops"] + attention_flops(c, counts[d_max]["dense_pairs"])
            )
            / 1e6,  # fmt: skip
            "search_matmul_mflop": counts[d_max]["matmul_flops"] / 1e6,
            "matmul_mflop_flopcounter": {k: v / 1e6 for k, v in counted.items()},
            "search_visible_pairs": counts[d_max]["visible_pairs"],
            "search_dense_pairs": counts[d_max]["dense_pairs"],
        },
        "threads": {},
    }
    calls = {
        "free_hf": lambda: free(ctxs["hf"]),
        "free_kernel": free,
        "search_torch": search("torch"),
        "search_kernel": search("kernel"),
        "search_torch_depth_1": search("torch", 1),
        "search_kernel_depth_1": search("kernel", 1),
    }
    saved = torch.get_num_threads()
    for th in threads:
        torch.set_num_threads(th)
        for fn in calls.values():
            fn()  # warm: the kernels' builds, allocations
        names = [*calls, "sgemm"]
        per_round = []
        for r in range(rounds):
            shift = r * len(names) // max(rounds, 1)
            order = names[shift:] + names[:shift]
            t = {}
            for name in order:
                if name == "sgemm":
                    t["sgemm"], t["sgemm_cpu"] = sgemm_rates()
                    continue
                with _KernelClock() as clock:
                    t[name], t[f"{name}_cpu"] = timed(calls[name])
                if name == "search_kernel":
                    t["tree_kernel_s"], t["tree_kernel_cpu_s"] = clock.seconds, clock.cpu_seconds
            per_round.append(t)
        med = {k: statistics.median(t[k] for t in per_round) for k in per_round[0]}
        # floors in seconds at the sgemm rate per wall second and per CPU second
        rate, rate_cpu = med["sgemm"] * 1e9, med["sgemm_cpu"] * 1e9
        out = {"sgemm_gflops": med["sgemm"], "sgemm_gflops_per_cpu_s": med["sgemm_cpu"]}
        for when, free_name, engine in (
            ("before", "free_hf", "torch"),
            ("after", "free_kernel", "kernel"),
        ):
            f, s_ = med[free_name], med[f"search_{engine}"]
            f_cpu, s_cpu = med[f"{free_name}_cpu"], med[f"search_{engine}_cpu"]
            out[when] = {
                "context_engine": "hf" if when == "before" else ctx.engine,
                "tree_engine": engine,
                "model_free_ms": f * 1e3,
                "model_free_cpu_ms": f_cpu * 1e3,
                "model_free_x_floor": f / (B * free_floor / rate),
                "model_free_x_floor_cpu": f_cpu / (B * free_floor / rate_cpu),
                "search_ms": s_ * 1e3,
                "search_cpu_ms": s_cpu * 1e3,
                "search_depth_1_ms": med[f"search_{engine}_depth_1"] * 1e3,
                "search_x_floor": s_ / (B * search_floor / rate),
                "search_x_floor_cpu": s_cpu / (B * search_floor / rate_cpu),
                "planned_step_ms": (f + s_) * 1e3,
                "planned_step_cpu_ms": (f_cpu + s_cpu) * 1e3,
                "planned_x_floor": (f + s_) / (B * (free_floor + search_floor) / rate),
                "planned_x_floor_cpu": (f_cpu + s_cpu)
                / (B * (free_floor + search_floor) / rate_cpu),
                "planned_over_model_free": (f + s_) / f,
                "projected_eval_min": project(
                    spec, K, d_max, c, f, med[f"search_{engine}_depth_1"], s_
                )
                / 60,
                # on an idle machine: the CPU seconds spread over the threads without waiting
                "projected_eval_min_idle": project(
                    spec,
                    K,
                    d_max,
                    c,
                    f_cpu / th,
                    med[f"search_{engine}_depth_1_cpu"] / th,
                    s_cpu / th,
                )
                / 60,
            }
        out["after"]["tree_kernel_share"] = med["tree_kernel_s"] / med["search_kernel"]
        out["after"]["tree_kernel_cpu_ms"] = med["tree_kernel_cpu_s"] * 1e3
        ratio = {
            "planned_step": [(t["free_hf"] + t["search_torch"]) / (t["free_kernel"] + t["search_kernel"]) for t in per_round],
            "planned_step_cpu": [(t["free_hf_cpu"] + t["search_torch_cpu"]) / (t["free_kernel_cpu"] + t["search_kernel_cpu"]) for t in per_round],
            "search": [t["search_torch"] / t["search_kernel"] for t in per_round],
            "search_cpu": [t["search_torch_cpu"] / t["search_kernel_cpu"] for t in per_round],
            "model_free": [t["free_hf"] / t["free_kernel"] for t in per_round],
            "model_free_cpu": [t["free_hf_cpu"] / t["free_kernel_cpu"] for t in per_round],
        }  # fmt: skip
        out["speedup"] = {k: statistics.median(v) for k, v in ratio.items()}
        out["speedup_rounds"] = ratio
        out["rounds"] = per_round
        if profile_ops:
            out["profile_ms"] = {
                "search_kernel": _top_ops(calls["search_kernel"]),
                "search_torch": _top_ops(calls["search_torch"]),
                "free_kernel": _top_ops(free),
                "free_hf": _top_ops(calls["free_hf"]),
            }
        row["threads"][th] = out
        brief = {k: out[k] for k in ("sgemm_gflops", "sgemm_gflops_per_cpu_s", "speedup")}
        brief.update({w: {k: round(v, 3) if isinstance(v, float) else v for k, v in out[w].items()}
                      for w in ("before", "after")})  # fmt: skip
        print(env, mode, f"threads {th}", json.dumps(brief), flush=True)
    torch.set_num_threads(saved)
    return row


def project(spec, K: int, d_max: int, c, free_s: float, depth_1_s: float, full_s: float) -> float:
    """Seconds of a planned evaluation: 100 episodes of H steps, a model-free step each, a search
    once the context holds K transitions, cut at the steps left in the episode; the search's cost
    linear in its imagined tokens between depth 1 and ``d_max``."""
    A, beams = c.action_dim, c.plan_beams

    def tree_tokens(depth: int) -> int:
        return sum(depth_tokens(A, depth, beams))

    n1, nmax = tree_tokens(1), tree_tokens(d_max)
    per_token = (full_s - depth_1_s) / max(nmax - n1, 1)
    H, total = spec.horizon, 0.0
    for s in range(100 * H):
        total += free_s
        if s + 1 >= K:
            total += depth_1_s + per_token * (tree_tokens(min(d_max, H - s % H)) - n1)
    return total


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--envs", nargs="+", default=["darkroom", "darkroom-permuted"])
    p.add_argument("--mode", default="window", choices=["window", "cache"])
    p.add_argument(
        "--rollouts", type=int, default=4, help="copies of every test task (cpu preset: 4)"
    )
    p.add_argument("--batch", type=int, default=None, help="batch size instead of tasks x rollouts")
    p.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument(
        "--ties",
        default="index",
        choices=["index", "policy"],
        help="the beam search's tie order below depth 0 (index: the reference's)",
    )
    p.add_argument("--profile", action="store_true", help="the top torch ops of each path")
    p.add_argument("--json", default=None)
    args = p.parse_args()
    if tree_attention.available() is not None:
        raise SystemExit(f"the tree attention kernel is unavailable: {tree_attention.available()}")
    out = {
        "cpu": cpu_model(),
        "machine": platform.machine(),
        "torch": torch.__version__,
        "load_average_start": os.getloadavg(),
        "env": {k: os.environ.get(k) for k in ("OMP_WAIT_POLICY", "OMP_NUM_THREADS")},
        "args": vars(args),
        "envs": {},
    }
    for env in args.envs:
        out["envs"][env] = measure(env, args.mode, args.batch, args.rollouts, args.threads,
                                   args.rounds, args.profile, args.ties)  # fmt: skip
        out["load_average_end"] = os.getloadavg()
        if args.json:  # after every env: a long run cut short keeps what it measured
            write_json_atomic(out, args.json)


if __name__ == "__main__":
    main()
