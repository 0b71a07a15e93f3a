"""``lhf push``: upload a history dataset, a selection or a checkpoint to a Hub repo."""

from __future__ import annotations

import argparse
import json

HELP = "push a history dataset, LHF selection or model checkpoint folder to a Hugging Face Hub repo"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "push",
        help=HELP,
        description=HELP
        + ".  One commit (all or nothing), with a card naming the repo; history datasets get the "
        "v3.0 tag.  The endpoint and token come from HF_ENDPOINT / HF_TOKEN (or `hf auth login`).",
    )
    p.add_argument("path", help="artifact folder (lhf collect / filter / train output)")
    p.add_argument("--repo-id", required=True, metavar="ORG/NAME", help="target repo (created)")
    p.add_argument("--private", action="store_true", help="create the repo private")
    p.add_argument("--revision", default=None, help="branch to commit to (created; default main)")
    p.add_argument("--token", default=None, help="write token (default: the logged-in one)")
    p.add_argument("--message", default=None, help="commit message")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.hub import push  # deferred: heavy

    result = push(
        args.path,
        args.repo_id,
        private=args.private,
        revision=args.revision,
        token=args.token,
        commit_message=args.message,
    )
    print(json.dumps(result, indent=2))
    print(
        f"pushed {result['kind']} to {result['repo_type']} repo {args.repo_id} ({result['commit'][:12]})"
    )
    return 0
