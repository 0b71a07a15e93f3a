"""``lhf compare``: relative enhancement of LHF over each backbone, as in the paper's tables."""

from __future__ import annotations

import argparse

from lhf_hf.configs.commands import CompareOptions

from .evaluate import COMPARE_HELP
from .flags import add_params, add_progress, values

# what compare refuses (evaluation/compare.py checks it; docs/evaluation.md): said in --help so
# that a refused comparison is no surprise
REFUSED = (
    "Refused, with the runs named: runs on different envs or with different episode counts; a "
    "backbone on one side only; one backbone's runs evaluated with different settings (rollouts; "
    "with planning the gate, dynamics and depth-0 order); different context protocols (window vs "
    "streaming); runs paired in the given order on different splits or task sets; one run given "
    "twice; a damaged eval_results.json."
)


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "compare", help=COMPARE_HELP, description=COMPARE_HELP, epilog=REFUSED
    )
    fields = add_params(p, CompareOptions)
    add_progress(p)  # the libraries' bars (lhf_hf.cli.main)
    p.set_defaults(func=run, fields=fields)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.evaluation import compare  # deferred: heavy (torch, matplotlib)

    options = CompareOptions(**values(args, args.fields))
    r = compare(options.baseline, options.lhf, options.out, options.overwrite)
    print(r["table"])
    if options.out:
        print(f"\ntable: {options.out}/compare.md  figure: {options.out}/compare.png")
    return 0
