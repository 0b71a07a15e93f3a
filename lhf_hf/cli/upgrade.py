"""``lhf upgrade``: rewrite a dataset of lhf's earlier layout in the current one, in place."""

from __future__ import annotations

import argparse

from lhf_hf.configs.commands import UpgradeOptions

from .flags import add_params, add_progress, values

HELP = "rewrite a dataset of lhf's earlier layout (before LeRobot's reader could load it) in place"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("upgrade", help=HELP, description=HELP)
    fields = add_params(p, UpgradeOptions, positional=("path",))
    add_progress(p)  # the libraries' bars (lhf_hf.cli.main)
    p.set_defaults(func=run, fields=fields)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.histories.upgrade import upgrade  # deferred: heavy (pyarrow, datasets)

    upgrade(UpgradeOptions(**values(args, args.fields)).path)
    return 0
