"""Entry point of the ``lhf`` console script (also ``python -m lhf_hf``).

Each command imports what it runs inside its ``run`` (``# deferred: heavy``): those modules pull in
torch, transformers and datasets, and ``lhf --help`` or a bad flag should not wait for them.
"""

from __future__ import annotations

import argparse
import sys

from lhf_hf import __version__
from lhf_hf.utils.signals import Terminated, ignore_interrupts, sigterm_raises

from . import collect, compare, derive, envs, evaluate, filter, push, reproduce, train, verify

#: Subcommands, in the order ``lhf --help`` lists them.  Each module has ``add_parser``.
COMMANDS = [envs, collect, derive, filter, train, evaluate, compare, push, reproduce, verify]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lhf",
        description="Learning history filtering for in-context RL on the Hugging Face stack.",
    )
    parser.add_argument("--version", action="version", version=f"lhf_hf {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line ``argv``, or this program's own (``argv`` None: the console script and
    ``python -m lhf_hf``), and return its exit code.  As the program, once it has handled an
    interrupt it ignores further ones while it exits, so that a double Ctrl-C ends it with 130 as a
    single one does; called with ``argv`` (tests, other programs) it leaves signals as they were."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        with sigterm_raises():  # kill / timeout clean up like Ctrl-C
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        if argv is None:
            ignore_interrupts()
        print(f"lhf {args.command}: interrupted", file=sys.stderr)
        return 130
    except Terminated as exc:
        if argv is None:
            ignore_interrupts()
        print(f"lhf {args.command}: terminated", file=sys.stderr)
        return int(exc.code)
    except (
        KeyError,
        ValueError,
        IndexError,
        TypeError,
        ImportError,
        FileNotFoundError,
        FileExistsError,
        RuntimeError,
    ) as exc:
        # User errors: one clear line, no traceback.
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"lhf {args.command}: error: {msg}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
