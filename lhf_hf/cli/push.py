"""``lhf push``: upload a history dataset, a selection or a checkpoint to a Hub repo."""

from __future__ import annotations

import argparse
import json

from lhf_hf.configs.commands import PushOptions

from .flags import add_params, add_progress, values

HELP = "push a history dataset, LHF selection or model checkpoint folder to a Hugging Face Hub repo"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "push",
        help=HELP,
        description=HELP
        + ".  One commit (all or nothing), with a card naming the repo; history datasets get the "
        "v3.0 tag.  The endpoint and token come from HF_ENDPOINT / HF_TOKEN (or `hf auth login`).",
    )
    fields = add_params(p, PushOptions, positional=("path",))
    add_progress(p)  # huggingface_hub's upload bars (lhf_hf.cli.main)
    p.set_defaults(func=run, fields=fields)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.hub import push  # deferred: heavy (every artifact kind: datasets, transformers)

    options = PushOptions(**values(args, args.fields))
    result = push(
        options.path,
        options.repo_id,
        private=options.private,
        revision=options.revision,
        token=options.token,
        commit_message=options.message,
        source_repo=options.source_repo,
    )
    print(json.dumps(result, indent=2))
    print(
        f"pushed {result['kind']} to {result['repo_type']} repo {options.repo_id} ({result['commit'][:12]})"
    )
    return 0
