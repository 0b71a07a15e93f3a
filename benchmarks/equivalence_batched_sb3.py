"""Print and plot the mean learning curves of the batched and SB3 collectors (paper protocol).

    python benchmarks/equivalence_batched_sb3.py --env darkroom --tasks 0,20,40,60 --histories 100 \
        --steps 1000 --sb3-seeds 0 1 2 3 --batched-seeds 0 1 --out results/equivalence

Each batched curve must lie inside the 99% prediction interval of SB3's seed-to-seed spread
(mean +/- t * sd * sqrt(1 + 1/S), S SB3 seeds) at every block of 5 episodes.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from lhf_hf.collection.batched_collector import resolve_ppo_backend
from lhf_hf.collection.equivalence import compare
from lhf_hf.configs.collect import CollectConfig


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="darkroom")
    p.add_argument("--tasks", default="0,20,40,60")
    p.add_argument("--histories", type=int, default=100)
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--sb3-seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    p.add_argument("--batched-seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--ppo-backend", default="auto", choices=["auto", "kernel", "torch"])
    p.add_argument("--out", default="results/equivalence")
    args = p.parse_args()
    tasks = [int(t) for t in args.tasks.split(",")]
    backend = resolve_ppo_backend(CollectConfig(args.env, ppo_backend=args.ppo_backend))
    cmp = compare(
        args.env,
        tasks,
        args.histories,
        args.steps,
        args.sb3_seeds,
        args.batched_seeds,
        ppo_backend=backend,
    )
    print(cmp.report())
    print(f"inside the band at every block: {bool(cmp.inside.all())}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cmp.plot(out / f"{args.env}.png")
    (out / f"{args.env}.json").write_text(
        json.dumps(
            {
                "env_id": args.env,
                "tasks": tasks,
                "histories": args.histories,
                "steps": args.steps,
                "sb3_seeds": args.sb3_seeds,
                "batched_seeds": args.batched_seeds,
                "ppo_backend": backend,
                "sb3_curves": cmp.sb3.tolist(),
                "batched_curves": cmp.batched.tolist(),
                "inside_every_block": bool(cmp.inside.all()),
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
