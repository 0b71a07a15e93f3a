"""Training steps against their FLOP floor: the torch attention path vs the C++ attention kernel.

    python benchmarks/bench_train_floor.py --dataset data/dr100 [--objectives ad dpt dicp]
        [--contexts 80 200] [--threads 1 2] [--steps 6] [--warmup 2] [--rounds 3] [--json OUT]

For each objective x context x thread count: the paper preset (4 layers, 4 heads, hidden 32, head
dim 8, attention and embedding dropout 0.1), batch 64 windows, every-position labels, one plain
training step (forward, backward, clipping, AdamW; ``bench_train.plain_loop``, the Trainer's
settings) on the same windows for both attention paths:

- ``torch``: ``lhf_sdpa`` (lhf_hf/modeling/train_attention.py), the default before the kernel;
- ``kernel``: ``lhf_kernel`` (lhf_hf/modeling/attention_kernel.py).

The floor: the step's FLOPs as torch's ``FlopCounterMode`` counts them (forward and backward of the
torch path: the attention's matmuls over every (query, key) pair, masked or not, as the issue
counted them; the optimiser's elementwise work is not counted), at the machine's sgemm rate
measured in the same process: a (1024, 1024) @ (1024, 1024) float32 ``torch.mm`` at the same thread
count, best of 3, measured in every round beside the steps.  ``x_floor`` = ms/step / floor ms.

The machine is shared and its speed drifts, so the two paths and the sgemm rate run in ``--rounds``
rounds in an order rotated each round; each number is the median over rounds, and the speed-up is
the median of per-round ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time

import torch
from bench_train import batches, plain_loop
from torch.utils.flop_counter import FlopCounterMode

from lhf_hf.collection.backend_verdict import cpu_model
from lhf_hf.configs import TrainConfig
from lhf_hf.modeling import attention_kernel, train_attention
from lhf_hf.training import build_trainer
from lhf_hf.utils.io import write_json_atomic

PATHS = {"torch": train_attention.NAME, "kernel": attention_kernel.NAME}


def sgemm_gflops(n: int = 1024, repeats: int = 3) -> float:
    """The float32 matmul rate at torch's current thread count (best of ``repeats``)."""
    a, b = torch.randn(n, n), torch.randn(n, n)
    torch.mm(a, b)
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        torch.mm(a, b)
        best = min(best, time.perf_counter() - t)
    return 2 * n**3 / best / 1e9


def step_flops(trainer, batch) -> int:
    """FLOPs of one forward + backward of the torch path, as FlopCounterMode counts them."""
    model = type(trainer.model)(trainer.model.config).train()
    model.config._attn_implementation = PATHS["torch"]
    with FlopCounterMode(display=False) as counter:
        model(**batch).loss.backward()
    return counter.get_total_flops()


class _KernelClock:
    """Wall time spent in the attention kernel's calls (forward and backward), to split a
    kernel-path step into attention and the rest (what the kernel cannot speed up)."""

    def __init__(self):
        self.seconds = 0.0
        self._run = attention_kernel._run

    def __enter__(self):
        def timed(*args):
            t = time.perf_counter()
            try:
                return self._run(*args)
            finally:
                self.seconds += time.perf_counter() - t

        attention_kernel._run = timed
        return self

    def __exit__(self, *exc):
        attention_kernel._run = self._run


def measure(trainer, data, warmup: int, rounds: int) -> dict:
    config = trainer.model.config
    per_round = []
    names = ["torch", "kernel", "sgemm"]
    for r in range(rounds):
        order = names[r % 3 :] + names[: r % 3]
        t = {}
        for name in order:
            if name == "sgemm":
                t[name] = sgemm_gflops()
                continue
            saved = config._attn_implementation
            config._attn_implementation = PATHS[name]
            try:
                with _KernelClock() as clock:
                    start = time.perf_counter()
                    t[name] = plain_loop(trainer, data, warmup)
                    if name == "kernel":  # every step's, warm-up included, over the loop's time
                        t["kernel_attention_share"] = clock.seconds / (time.perf_counter() - start)
            finally:
                config._attn_implementation = saved
        per_round.append(t)
    return {
        "rounds": per_round,
        "torch_s": statistics.median(t["torch"] for t in per_round),
        "kernel_s": statistics.median(t["kernel"] for t in per_round),
        "sgemm_gflops": statistics.median(t["sgemm"] for t in per_round),
        "speedup": statistics.median(t["torch"] / t["kernel"] for t in per_round),
        "kernel_attention_share": statistics.median(t["kernel_attention_share"] for t in per_round),
    }


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--dataset", required=True)
    p.add_argument("--objectives", nargs="+", default=["ad", "dpt", "dicp"])
    p.add_argument("--contexts", nargs="+", type=int, default=[80, 200])
    p.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    p.add_argument("--steps", type=int, default=6)
    p.add_argument("--warmup", type=int, default=2)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--json", default=None)
    args = p.parse_args()
    if attention_kernel.available() is not None:
        raise SystemExit(f"the attention kernel is unavailable: {attention_kernel.available()}")
    tmp = tempfile.mkdtemp(prefix="bench-floor-")
    results = {
        "cpu": cpu_model(),
        "machine": platform.machine(),
        "torch": torch.__version__,
        "steps": args.steps,
        "warmup": args.warmup,
        "rounds": args.rounds,
        "batch_size": args.batch_size,
        # OMP_WAIT_POLICY=PASSIVE: on a loaded machine torch's 2-thread ops otherwise spin-wait
        # for a descheduled peer (BENCHMARKS.md)
        "env": {k: os.environ.get(k) for k in ("OMP_WAIT_POLICY", "OMP_NUM_THREADS")},
        "rows": [],
    }
    saved_threads = torch.get_num_threads()
    for objective in args.objectives:
        for context in args.contexts:
            cfg = TrainConfig(
                dataset=args.dataset,
                objective=objective,
                out=f"{tmp}/{objective}-{context}",
                preset="paper",
                context_length=context,
                max_steps=args.steps,
                batch_size=args.batch_size,
                save_steps=10**6,
                logging_steps=10**6,
                overwrite=True,
                attention_kernel="torch",
            )
            trainer, _ = build_trainer(cfg, progress=False)
            data = batches(trainer, args.steps)
            flops = step_flops(trainer, data[0])
            for threads in args.threads:
                torch.set_num_threads(threads)
                m = measure(trainer, data, args.warmup, args.rounds)
                floor_s = flops / (m["sgemm_gflops"] * 1e9)
                row = {
                    "objective": objective,
                    "context": context,
                    "tokens": context * trainer.model.config.tokens_per_transition,
                    "threads": threads,
                    "gflop_per_step": flops / 1e9,
                    "floor_ms": floor_s * 1e3,
                    "torch_ms": m["torch_s"] * 1e3,
                    "kernel_ms": m["kernel_s"] * 1e3,
                    "torch_x_floor": m["torch_s"] / floor_s,
                    "kernel_x_floor": m["kernel_s"] / floor_s,
                    # the kernel path's step without its attention calls, over the floor: what
                    # the step would be if attention cost nothing
                    "rest_x_floor": m["kernel_s"] * (1 - m["kernel_attention_share"]) / floor_s,
                    **{
                        k: m[k]
                        for k in ("sgemm_gflops", "speedup", "kernel_attention_share", "rounds")
                    },
                }
                results["rows"].append(row)
                if args.json:  # after every row: a long grid cut short keeps what it measured
                    write_json_atomic(results, args.json)
                print(
                    f"{objective} ctx {context} threads {threads}: {flops / 1e9:.2f} GFLOP, "
                    f"sgemm {m['sgemm_gflops']:.0f} GFLOP/s, floor {row['floor_ms']:.0f} ms | "
                    f"torch {row['torch_ms']:.0f} ms ({row['torch_x_floor']:.1f}x) | "
                    f"kernel {row['kernel_ms']:.0f} ms ({row['kernel_x_floor']:.1f}x, attention "
                    f"{m['kernel_attention_share']:.0%}, rest {row['rest_x_floor']:.1f}x) | "
                    f"speed-up {m['speedup']:.2f}x",
                    flush=True,
                )
            torch.set_num_threads(saved_threads)
    print(json.dumps([{k: v for k, v in r.items() if k != "rounds"} for r in results["rows"]]))


if __name__ == "__main__":
    main()
