"""``lhf verify``: check an output folder against its manifest and its kind's own records."""

from __future__ import annotations

import argparse

from lhf_hf.configs.commands import VerifyOptions

from .flags import add_params, add_progress, values

HELP = (
    "check a dataset, selection, model or other lhf output folder, or a Hub repo id: files "
    "unchanged, contents consistent"
)


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("verify", help=HELP, description=HELP)
    fields = add_params(p, VerifyOptions, positional=("path",))
    add_progress(p)  # the libraries' bars (lhf_hf.cli.main)
    p.set_defaults(func=run, fields=fields)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.verify import verify  # deferred: heavy (every artifact kind's readers)

    r = verify(VerifyOptions(**values(args, args.fields)).path)
    for note in r["notes"]:
        print(f"note: {note}")
    if r["problems"]:
        print(f"{r['path']} ({r['kind']}): {len(r['problems'])} problem(s)")
        for problem in r["problems"]:
            print(f"  - {problem}")
        return 1
    print(f"{r['path']} ({r['kind']}): ok")
    return 0
