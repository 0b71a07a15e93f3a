"""``lhf derive``: datasets derived from a history dataset (``half``)."""

from __future__ import annotations

import argparse

HELP = "derive a dataset from a history dataset (half: the first 50%% of every history)"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("derive", help=HELP, description=HELP)
    p.add_argument("op", choices=["half"], help="half: the first --fraction of every history")
    p.add_argument("src", help="source dataset folder")
    p.add_argument("--out", required=True, help="dataset folder to write")
    p.add_argument(
        "--fraction", type=float, default=0.5, help="part of each history to keep (default 0.5)"
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resume", action="store_true")
    g.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.histories.derive import derive_half  # deferred: heavy

    ds = derive_half(
        args.src, args.out, fraction=args.fraction, overwrite=args.overwrite, resume=args.resume
    )
    print(f"wrote {ds}")
    return 0
