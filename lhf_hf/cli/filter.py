"""``lhf filter``: LHF (or an ablation) on a history dataset -> a selection (+ a materialised dataset)."""

from __future__ import annotations

import argparse
import json

HELP = (
    "filter a history dataset with LHF: write a selection (and optionally a materialised dataset)"
)


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("filter", help=HELP, description=HELP)
    p.add_argument("dataset", help="history dataset folder or Hub dataset repo ORG/NAME[@REV]")
    p.add_argument(
        "--out", required=True, help="selection folder (selection.parquet, filter_config.json, PNG)"
    )
    p.add_argument(
        "--strategy", default="linear", choices=["linear", "softmax", "none", "top-fraction"]
    )
    p.add_argument(
        "--lam", type=float, default=1.0, help="lambda: weight of Stability in U (default 1)"
    )
    p.add_argument("--alpha", type=float, default=0.125, help="softmax temperature (default 0.125)")
    p.add_argument(
        "--fraction", type=float, default=0.5, help="kept share for --strategy top-fraction"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the acceptance draws")
    p.add_argument(
        "--r-max",
        type=float,
        default=None,
        help="maximal return (default: the env's optimum per task)",
    )
    p.add_argument("--scan-order", default="descending", choices=["descending", "dataset"])
    p.add_argument(
        "--materialize",
        metavar="OUT_DATASET",
        default=None,
        help="also write the selected histories (with repeats) as a dataset",
    )
    p.add_argument(
        "--overwrite", action="store_true", help="replace an existing selection / dataset"
    )
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.configs import FilterConfig  # deferred: heavy
    from lhf_hf.filtering.run import run_filter  # deferred: heavy

    config = FilterConfig(
        strategy=args.strategy,
        lam=args.lam,
        alpha=args.alpha,
        fraction=args.fraction,
        seed=args.seed,
        r_max=args.r_max,
        scan_order=args.scan_order,
    )
    summary = run_filter(
        args.dataset, args.out, config, materialize_to=args.materialize, overwrite=args.overwrite
    )
    print(json.dumps(summary, indent=2))
    print(f"selection: {args.out}/selection.parquet  plot: {args.out}/selection.png")
    return 0
