"""Batched collector vs the SB3 collector on the same machine in one run (issue: batched PPO >= 50x).

    python benchmarks/bench_collect_ratio.py [--env darkroom] [--sb3-tasks 2] [--ppo-backend auto]
        [--json OUT]

Runs, back to back: the batched collector on the env's full paper dataset (every task x 100
histories x 1,000 transitions, ``--ppo-backend``: ``auto`` measures which is faster here), the SB3 collector on ``--sb3-tasks`` tasks
with 2 workers (its rate is linear in tasks: one learner per task), then the batched collector
again, so that a drift of this shared machine's speed hits both sides.  The ratio is the mean of the
two batched rates over the SB3 rate.  Writing the dataset is included on both sides.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time

import torch

from lhf_hf.collection import backend_verdict, collect
from lhf_hf.configs import CollectConfig


def run(config: CollectConfig) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        collect(config, f"{tmp}/d", progress=False)
        seconds = time.perf_counter() - start
    frames = len(config.tasks) * config.frames_per_task
    return {
        "collector": config.collector,
        "ppo_backend": config.ppo_backend,
        "tasks": len(config.tasks),
        "workers": config.workers,
        "frames": frames,
        "seconds": round(seconds, 2),
        "transitions_per_s": round(frames / seconds, 1),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="darkroom")
    p.add_argument("--sb3-tasks", type=int, default=2)
    p.add_argument("--ppo-backend", default="auto", choices=["auto", "kernel", "torch"])
    p.add_argument("--json")
    args = p.parse_args()
    batched = lambda: CollectConfig(args.env, collector="batched", ppo_backend=args.ppo_backend)  # noqa: E731
    sb3_tasks = ",".join(str(t) for t in range(args.sb3_tasks))
    rows = [run(batched())]
    print(rows[-1], flush=True)
    rows.append(run(CollectConfig(args.env, tasks=sb3_tasks, workers=2)))
    print(rows[-1], flush=True)
    rows.append(run(batched()))
    print(rows[-1], flush=True)
    b = (rows[0]["transitions_per_s"] + rows[2]["transitions_per_s"]) / 2
    out = {
        "command": "python benchmarks/bench_collect_ratio.py "
        + " ".join(f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items() if v is not None),
        "env": args.env,
        "runs": rows,
        "batched_mean_transitions_per_s": round(b, 1),
        "sb3_transitions_per_s": rows[1]["transitions_per_s"],
        "ratio": round(b / rows[1]["transitions_per_s"], 2),
        "torch": torch.__version__,
        "machine": backend_verdict.machine(),  # CPU model, instruction set, the kernel's -march
        "cores": torch.get_num_threads(),
    }
    print(f"batched / SB3 = {out['ratio']}x")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
