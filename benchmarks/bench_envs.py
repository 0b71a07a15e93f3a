"""Batched gridworld env-steps/s against the gymnasium wrapper stepped in a Python loop (same run).

    python benchmarks/bench_envs.py [--env darkroom] [--batch 100 1000] [--seconds 2] [--json OUT]

Both sides step B copies with the same pre-drawn random actions and reset at the horizon; the
loop baseline steps B ``GridworldEnv`` objects one by one (what a per-env Python collector does).
Reported: env-steps per second (B * steps / wall time) and the ratio batched / loop.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

from lhf_hf.envs import get_spec, make, make_batched


def _time(fn, seconds: float) -> float:
    """Run ``fn`` (which returns how many env-steps it did) for ~``seconds``; best of 3 rates."""
    rates = []
    for _ in range(3):
        done, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds / 3:
            done += fn()
        rates.append(done / (time.perf_counter() - start))
    return max(rates)


def bench(env_id: str, batch: int, seconds: float, seed: int = 0) -> dict:
    spec = get_spec(env_id)
    rng = np.random.default_rng(seed)
    tasks = rng.integers(0, spec.num_tasks, batch)
    actions = rng.integers(0, 5, (spec.horizon, batch))  # (H, B)

    core = make_batched(env_id, tasks)

    def batched_episode() -> int:
        core.reset()
        for t in range(spec.horizon):
            core.step(actions[t])
        return batch * spec.horizon

    envs = [make(env_id, int(t)) for t in tasks]
    actions_py = actions.tolist()

    def loop_episode() -> int:
        for e in envs:
            e.reset()
        for t in range(spec.horizon):
            row = actions_py[t]
            for e, a in zip(envs, row, strict=True):
                e.step(a)
        return batch * spec.horizon

    batched = _time(batched_episode, seconds)
    loop = _time(loop_episode, seconds)
    return {
        "env_id": env_id,
        "batch": batch,
        "batched_steps_per_s": batched,
        "loop_steps_per_s": loop,
        "ratio": batched / loop,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", nargs="+", default=["darkroom", "dark-key-to-door"])
    p.add_argument("--batch", type=int, nargs="+", default=[100, 1000])
    p.add_argument("--seconds", type=float, default=3.0, help="time budget per measurement")
    p.add_argument("--json", help="write the results here")
    args = p.parse_args()
    results = [bench(e, b, args.seconds) for e in args.env for b in args.batch]
    print(f"{'env':<18} {'B':>5} {'batched steps/s':>16} {'loop steps/s':>13} {'ratio':>7}")
    for r in results:
        print(
            f"{r['env_id']:<18} {r['batch']:>5} {r['batched_steps_per_s']:>16,.0f} "
            f"{r['loop_steps_per_s']:>13,.0f} {r['ratio']:>6.0f}x"
        )
    if args.json:
        meta = {
            "python": platform.python_version(),
            "numpy": np.__version__,
            "machine": platform.machine(),
            "processor": platform.processor() or platform.machine(),
        }
        with open(args.json, "w") as f:
            json.dump({"meta": meta, "results": results}, f, indent=2)


if __name__ == "__main__":
    main()
