"""Key-to-Door collection time vs its FLOP floor, measured in the same run (alternating).

    python benchmarks/bench_floor_ratio.py [--cycles 3] [--tasks-per-chunk 243] [--json OUT]

This VM's speed drifts by tens of percent within minutes (the batched-matmul rate went from 141 to
203 GFLOP/s over one 72-minute collection), so a floor measured at another time says little about a
run. Here each cycle measures the (100x64)@(64x64) bmm rate (best of 5), collects and writes one chunk
of ``--tasks-per-chunk`` Key-to-Door tasks with ``lhf_hf.collection.collect()`` (the CLI's path,
writing and the chunk's assembly included), and measures the rate again; the chunk's floor is its
PPO-update FLOPs at the better of the two adjacent rates (the stricter floor). The full dataset is
6,561 / tasks-per-chunk such chunks, so the per-chunk ratio is the full run's ratio.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

from bench_ppo_step import matmul_floor_ms, minibatch_steps_per_learner, step_flops

from lhf_hf.collection import collect
from lhf_hf.configs import CollectConfig


def bmm_rate(repeats: int = 5) -> float:
    return max(matmul_floor_ms(81, 100)["bmm_gflops"] for _ in range(repeats))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cycles", type=int, default=3)
    p.add_argument("--tasks-per-chunk", type=int, default=243)
    p.add_argument("--json", default=None)
    a = p.parse_args()
    K = a.tasks_per_chunk
    cfg0 = CollectConfig("dark-key-to-door", collector="batched")
    ppo = cfg0.ppo
    steps_per_learner = minibatch_steps_per_learner(cfg0)
    chunk_flops = K * steps_per_learner * step_flops(1, ppo.batch_size)
    cycles = []
    rate = bmm_rate()
    for c in range(a.cycles):
        tasks = list(range(c * K, (c + 1) * K))
        out = Path(tempfile.mkdtemp(prefix="lhf-floor-"))
        try:
            cfg = CollectConfig(
                "dark-key-to-door", tasks=tasks, collector="batched", tasks_per_chunk=K
            )
            t = time.perf_counter()
            collect(cfg, out / "ds", progress=False)
            wall = time.perf_counter() - t
        finally:
            shutil.rmtree(out, ignore_errors=True)
        after = bmm_rate()
        best = max(rate, after)
        floor = chunk_flops / (best * 1e9)
        cycles.append(
            {
                "tasks": [tasks[0], tasks[-1]],
                "wall_s": wall,
                "bmm_gflops_before": rate,
                "bmm_gflops_after": after,
                "floor_s": floor,
                "ratio": wall / floor,
            }
        )
        print(json.dumps(cycles[-1]))
        rate = after
    out = {
        "tasks_per_chunk": K,
        "minibatch_steps_per_learner": steps_per_learner,
        "flops_per_learner_step": step_flops(1, ppo.batch_size),
        "chunk_flops": chunk_flops,
        "cycles": cycles,
        "ratio_mean": sum(c["ratio"] for c in cycles) / len(cycles),
        "ratio_max": max(c["ratio"] for c in cycles),
    }
    print(json.dumps({k: v for k, v in out.items() if k != "cycles"}, indent=1))
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
