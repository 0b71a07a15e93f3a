"""SB3 collection throughput (transitions/s), paper protocol, with 1 and 2 worker processes.

    python benchmarks/bench_collect_sb3.py [--env darkroom dark-key-to-door] [--json OUT]

For each env: one full task (100 histories x 1000 transitions) with 1 worker, then two tasks with
2 workers (same run).  The full-dataset times are extrapolated from the 2-worker rate:
tasks x 100 x 1000 / rate.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time

from lhf_hf.collection import collect
from lhf_hf.configs import CollectConfig
from lhf_hf.envs import get_spec


def measure(env_id: str, tasks: str, workers: int, histories: int, steps: int) -> dict:
    cfg = CollectConfig(env_id, tasks=tasks, histories=histories, steps=steps, workers=workers)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        collect(cfg, f"{tmp}/d", progress=False)
        seconds = time.perf_counter() - start
    frames = len(cfg.tasks) * cfg.frames_per_task
    return {
        "env_id": env_id,
        "workers": workers,
        "tasks": len(cfg.tasks),
        "frames": frames,
        "seconds": seconds,
        "transitions_per_s": frames / seconds,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", nargs="+", default=["darkroom", "dark-key-to-door"])
    p.add_argument("--histories", type=int, default=100)
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--json", help="write the results here")
    args = p.parse_args()
    rows = []
    for env_id in args.env:
        train, _ = get_spec(env_id).split(0)
        one = measure(env_id, str(train[0]), 1, args.histories, args.steps)
        two = measure(env_id, f"{train[1]},{train[2]}", 2, args.histories, args.steps)
        n = get_spec(env_id).num_tasks
        full_h = n * args.histories * args.steps / two["transitions_per_s"] / 3600
        rows += [
            one,
            {
                **two,
                "speedup_vs_1_worker": two["transitions_per_s"] / one["transitions_per_s"],
                "full_dataset_hours_2_workers": full_h,
            },
        ]
    for r in rows:
        extra = (
            f"  x{r['speedup_vs_1_worker']:.2f} vs 1 worker; full {r['env_id']}: {r['full_dataset_hours_2_workers']:.1f} h"
            if "speedup_vs_1_worker" in r
            else ""
        )
        print(
            f"{r['env_id']:<18} workers={r['workers']} tasks={r['tasks']} {r['seconds']:7.1f} s "
            f"{r['transitions_per_s']:8,.0f} transitions/s{extra}"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)


if __name__ == "__main__":
    main()
