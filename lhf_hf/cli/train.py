"""``lhf train``: pretrain an AD / DPT / DICP model on a history dataset (optionally LHF-resampled)."""

from __future__ import annotations

import argparse
import os

from lhf_hf.configs import TrainConfig

from .flags import add_params, add_progress, progress, values

HELP = "pretrain an ICRL model (AD, DPT or DICP) with transformers.Trainer"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "train",
        help=HELP,
        description=HELP
        + (
            '. Runs as is or under `accelerate launch --config_file "$(lhf accelerate-config)" '
            "-m lhf_hf train ...` (CPU data parallelism, 2 processes)."
        ),
    )
    fields = add_params(
        p, TrainConfig, skip=("resume", "overwrite"), flags={"training_args": "--training-arg"}
    )
    fields += add_params(
        p, TrainConfig, only=("resume", "overwrite"), group=p.add_mutually_exclusive_group()
    )
    add_progress(p)
    p.set_defaults(func=run, fields=fields)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.training import train  # deferred: heavy (torch, transformers)

    cfg = TrainConfig(**values(args, args.fields))
    out = train(cfg, progress=progress(args))
    if os.environ.get("RANK", "0") == "0":  # one line under accelerate launch, not one per process
        print(f"model: {out}  (card: {out}/README.md, config: {out}/train_config.json)")
        if cfg.push_to_hub:
            print(f"pushed to the model repo {cfg.push_to_hub}")
    return 0
