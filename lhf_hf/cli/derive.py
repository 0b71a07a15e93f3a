"""``lhf derive``: datasets derived from a history dataset (``half``)."""

from __future__ import annotations

import argparse

from lhf_hf.configs.commands import DeriveOptions, OutputOptions

from .flags import add_params, values

HELP = "derive a dataset from a history dataset (half: the first 50%% of every history)"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("derive", help=HELP, description=HELP.replace("%%", "%"))
    derive = add_params(p, DeriveOptions, positional=("op", "src"))
    output = add_params(p, OutputOptions, only=("out", "progress"))
    output += add_params(
        p, OutputOptions, only=("resume", "overwrite"), group=p.add_mutually_exclusive_group()
    )
    p.set_defaults(func=run, derive=derive, output=output)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.histories.derive import DERIVATIONS  # deferred: heavy (datasets)

    options = DeriveOptions(**values(args, args.derive))
    output = OutputOptions(**values(args, args.output))
    ds = DERIVATIONS[options.op](
        options.src,
        output.out,
        fraction=options.fraction,
        overwrite=output.overwrite,
        resume=output.resume,
        progress=output.progress,
    )
    print(f"wrote {ds}")
    return 0
