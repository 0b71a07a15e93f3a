"""``lhf collect``: collect learning histories into a dataset folder."""

from __future__ import annotations

import argparse

HELP = "collect learning histories (SB3 PPO/SAC) into a LeRobot-style dataset"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("collect", help=HELP, description=HELP)
    p.add_argument("env_id", help="environment id (see `lhf envs`)")
    p.add_argument("--out", required=True, help="dataset folder to write")
    p.add_argument(
        "--tasks",
        default="all",
        help="all | train | test | comma-separated task indices (default all)",
    )
    p.add_argument("--histories", type=int, default=100, help="histories per task (default 100)")
    p.add_argument(
        "--steps", type=int, default=1000, help="transitions per history, a multiple of the horizon"
    )
    p.add_argument("--protocol", default="paper", choices=["paper", "independent", "noisy"])
    p.add_argument(
        "--noisy-fraction", type=float, default=0.3, help="random histories under --protocol noisy"
    )
    p.add_argument("--algo", default="ppo", choices=["ppo", "sac"])
    p.add_argument(
        "--collector",
        default="sb3",
        choices=["sb3", "batched"],
        help="sb3: one SB3 learner per job (reference); batched: all learners of a chunk of tasks at once",
    )
    p.add_argument(
        "--tasks-per-chunk", type=int, default=None, help="batched: tasks trained together"
    )
    p.add_argument(
        "--device",
        default="cpu",
        help="batched: where the stacked PPO learners run, cpu (default) or cuda[:N]",
    )
    p.add_argument(
        "--ppo-backend",
        default="auto",
        choices=["auto", "kernel", "torch"],
        help="batched, CPU: PPO updates by the C++ kernel (built on first use with g++) or torch ops; "
        "auto (default): the kernel where it builds",
    )
    p.add_argument("--seed", type=int, default=0, help="root seed of the learners")
    p.add_argument(
        "--split-seed", type=int, default=0, help="train/test split seed (and Meta-World goals)"
    )
    p.add_argument(
        "--workers", type=int, default=None, help="parallel worker processes (default: all cores)"
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--resume", action="store_true", help="continue an interrupted collection in --out"
    )
    g.add_argument("--overwrite", action="store_true", help="replace the collection in --out")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    import gc

    from lhf_hf.collection import collect  # deferred: heavy
    from lhf_hf.configs import CollectConfig  # deferred: heavy

    kwargs = {} if args.workers is None else {"workers": args.workers}
    config = CollectConfig(
        env_id=args.env_id,
        tasks=args.tasks,
        histories=args.histories,
        steps=args.steps,
        protocol=args.protocol,
        algo=args.algo,
        collector=args.collector,
        seed=args.seed,
        split_seed=args.split_seed,
        noisy_fraction=args.noisy_fraction,
        tasks_per_chunk=args.tasks_per_chunk,
        device=args.device,
        ppo_backend=args.ppo_backend,
        **kwargs,
    )
    # A one-shot process: the objects alive now (torch, numpy, datasets, ...) live until exit, so
    # the cyclic GC need not rescan them on every full collection (~0.7 s per Key-to-Door chunk of
    # the batched collector's per-step allocations).
    gc.freeze()
    ds = collect(
        config,
        args.out,
        resume=args.resume,
        overwrite=args.overwrite,
        progress=not args.no_progress,
    )
    if ds is not None:
        print(f"wrote {ds}\ncard: {ds.root / 'README.md'}")
    else:  # a non-zero rank under accelerate launch: rank 0 assembles the dataset
        import os

        print(
            f"[rank {os.environ.get('RANK', '?')}] committed this rank's tasks; rank 0 wrote the dataset"
        )
    return 0
