"""``lhf reproduce``: one paper experiment end to end, stage by stage, to a report."""

from __future__ import annotations

import argparse

HELP = "run a paper experiment end to end (collect, filter, train, evaluate, compare) to report.md"


def add_parser(subparsers) -> argparse.ArgumentParser:
    from lhf_hf.reproduce import experiment_names  # deferred: heavy

    p = subparsers.add_parser(
        "reproduce",
        help=HELP,
        description=HELP + ".  Every stage is cached by its config's hash: a rerun resumes.",
    )
    p.add_argument("experiment", help=f"one of {experiment_names()} or a yaml path")
    p.add_argument("--preset", default="quick", choices=["quick", "cpu", "paper"])
    p.add_argument(
        "--runs", type=int, default=None, help="independent runs (default: the preset's)"
    )
    p.add_argument("--out", default=None, help="report folder (default results/EXPERIMENT-PRESET)")
    p.add_argument(
        "--work", default="runs/reproduce", help="stage cache: datasets, checkpoints, evaluations"
    )
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.reproduce import reproduce  # deferred: heavy

    reproduce(args.experiment, args.preset, args.runs, args.out, args.work)
    return 0
