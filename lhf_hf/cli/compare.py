"""``lhf compare``: relative enhancement of LHF over each backbone, as in the paper's tables."""

from __future__ import annotations

import argparse

from .evaluate import COMPARE_HELP


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("compare", help=COMPARE_HELP, description=COMPARE_HELP)
    p.add_argument("--baseline", nargs="+", required=True, help="evaluation folders without LHF")
    p.add_argument("--lhf", nargs="+", required=True, help="evaluation folders with LHF")
    p.add_argument("--out", default=None, help="folder for compare.md / compare.json / compare.png")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.evaluation import compare  # deferred: heavy

    r = compare(args.baseline, args.lhf, args.out)
    print(r["table"])
    if args.out:
        print(f"\ntable: {args.out}/compare.md  figure: {args.out}/compare.png")
    return 0
