"""``lhf train``: pretrain an AD / DPT / DICP model on a history dataset (optionally LHF-resampled)."""

from __future__ import annotations

import argparse
import os

HELP = "pretrain an ICRL model (AD, DPT or DICP) with transformers.Trainer"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "train",
        help=HELP,
        description=HELP
        + (
            ". Runs as is or under `accelerate launch --config_file training/accelerate/cpu_2proc.yaml "
            "-m lhf_hf train ...`."
        ),
    )
    p.add_argument(
        "--dataset", required=True, help="history dataset folder or Hub repo id ORG/NAME[@REV]"
    )
    p.add_argument(
        "--selection", default=None, help="LHF selection folder (`lhf filter`) or Hub repo id"
    )
    p.add_argument("--objective", required=True, choices=["ad", "dpt", "dicp"])
    p.add_argument("--out", required=True, help="output folder (checkpoints, model, card)")
    p.add_argument("--preset", default="paper", choices=["paper", "lightweight", "tiny"])
    p.add_argument("--max-steps", type=int, default=2000)
    p.add_argument("--batch-size", type=int, default=64, help="windows per step, all processes")
    p.add_argument(
        "--context-length", type=int, default=None, help="transitions (default: the env's)"
    )
    p.add_argument("--label-positions", default=None, choices=["all", "query"])
    p.add_argument("--lr", type=float, default=1e-2)
    p.add_argument("--warmup-steps", type=int, default=0)
    p.add_argument("--dynamics-coef", type=float, default=1.0, help="DICP's xi")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--save-steps", type=int, default=500)
    p.add_argument("--logging-steps", type=int, default=50)
    p.add_argument(
        "--push-to-hub",
        metavar="ORG/NAME",
        default=None,
        help="push checkpoints (during training) and the final model with its card to this model repo",
    )
    p.add_argument(
        "--hub-private", action="store_true", help="create the --push-to-hub repo private"
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resume", action="store_true", help="continue from the last checkpoint")
    g.add_argument("--overwrite", action="store_true", help="start afresh in an existing --out")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.configs import TrainConfig  # deferred: heavy
    from lhf_hf.training import train  # deferred: heavy

    cfg = TrainConfig(
        dataset=args.dataset,
        selection=args.selection,
        objective=args.objective,
        out=args.out,
        preset=args.preset,
        max_steps=args.max_steps,
        batch_size=args.batch_size,
        context_length=args.context_length,
        label_positions=args.label_positions,
        lr=args.lr,
        warmup_steps=args.warmup_steps,
        dynamics_coef=args.dynamics_coef,
        seed=args.seed,
        save_steps=args.save_steps,
        logging_steps=args.logging_steps,
        resume=args.resume,
        overwrite=args.overwrite,
        push_to_hub=args.push_to_hub,
        hub_private=args.hub_private,
    )
    out = train(cfg)
    if os.environ.get("RANK", "0") == "0":  # one line under accelerate launch, not one per process
        print(f"model: {out}  (card: {out}/README.md, config: {out}/train_config.json)")
        if cfg.push_to_hub:
            print(f"pushed to the model repo {cfg.push_to_hub}")
    return 0
