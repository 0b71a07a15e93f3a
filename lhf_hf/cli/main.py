"""Entry point of the ``lhf`` console script (also ``python -m lhf_hf``).

Each command imports what it runs inside its ``run`` (``# deferred: heavy``): those modules pull in
torch, transformers and datasets, and ``lhf --help`` or a bad flag should not wait for them.
"""

from __future__ import annotations

import argparse
import errno
import os
import signal
import sys
import traceback
from contextlib import nullcontext

from lhf_hf import __version__
from lhf_hf.errors import UserError
from lhf_hf.utils.launcher import launch_mismatch
from lhf_hf.utils.progress import library_bars
from lhf_hf.utils.signals import (
    Terminated,
    ignore_interrupts,
    interrupted_by,
    interrupts_raise_once,
    sigterm_raises,
)

from . import (
    accelerate_config,
    collect,
    compare,
    derive,
    envs,
    evaluate,
    filter,
    push,
    reproduce,
    train,
    upgrade,
    verify,
)
from .flags import progress

#: Subcommands, in the order ``lhf --help`` lists them.  Each module has ``add_parser``.
COMMANDS = [
    envs,
    collect,
    derive,
    filter,
    train,
    evaluate,
    compare,
    push,
    reproduce,
    verify,
    upgrade,
    accelerate_config,
]


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
    ``python -m lhf_hf``), and return its exit code.  As the program, the first Ctrl-C or SIGTERM
    interrupts the command and later ones are ignored (``utils.signals.interrupts_raise_once``):
    its cleanup runs whole and it ends with 130 or 143 however often the key is pressed.  Called
    with ``argv`` (tests, other programs), SIGTERM raises within the call only."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    mismatch = launch_mismatch()
    if mismatch:  # said first: the run that follows is not the one asked for
        print(f"lhf {args.command}: warning: {mismatch}", file=sys.stderr)
    program = argv is None
    if program:
        interrupts_raise_once()
    try:
        code = _run(args, program)
        sys.stdout.flush()  # here, where a closed pipe can still be caught (lhf_hf.cli.entry)
        if program:
            # Done: an interrupt now must not turn a finished run into a death by signal (the
            # interpreter's exit puts SIGINT's default action back where a Python handler is).
            ignore_interrupts()
        return code
    except BaseException as exc:
        sig = interrupted_by() if program else None
        if sig is None or isinstance(exc, KeyboardInterrupt | Terminated):
            raise
        # the interrupt surfaced as another error (a library wrapped it): it is still one
        word = "interrupted" if sig == signal.SIGINT else "terminated"
        print(f"lhf {args.command}: {word}{_completed()}", file=sys.stderr)
        return 128 + sig


def _run(args: argparse.Namespace, program: bool) -> int:
    """The command, with the outcomes every command shares turned into messages and exit codes."""
    try:
        # kill / timeout: as Ctrl-C; --no-progress: the libraries' bars too, for every command
        with nullcontext() if program else sigterm_raises(), library_bars(progress(args)):
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        if program:  # also after an interrupt some library code raised itself
            ignore_interrupts()
        print(f"lhf {args.command}: interrupted{_completed()}", file=sys.stderr)
        return 130
    except Terminated as exc:
        if program:
            ignore_interrupts()
        print(f"lhf {args.command}: terminated{_completed()}", file=sys.stderr)
        return int(exc.code)
    except UserError as exc:
        if program and interrupted_by() is not None:
            raise  # an interrupt a library wrapped: main reports it as the interrupt
        # An expected failure: one clear line (LHF_DEBUG=1: with its traceback).  Anything else
        # is a bug and keeps its traceback.
        if os.environ.get("LHF_DEBUG", "") not in ("", "0"):
            traceback.print_exc()
        print(f"lhf {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except MemoryError:
        print(
            f"lhf {args.command}: error: not enough memory for what was asked: ask for less "
            "(fewer --steps, --histories or tasks per chunk, a smaller --batch-size)",
            file=sys.stderr,
        )
        return 1
    except OSError as exc:
        if exc.errno not in _MACHINE_ERRNOS:
            raise
        where = f": {exc.filename}" if exc.filename else ""
        print(f"lhf {args.command}: error: {exc.strerror}{where}", file=sys.stderr)
        return 1


def _completed() -> str:
    """What an interrupted command had already finished (complete, kept), and what it had not
    written anything into yet (nothing to resume): said, not guessed."""
    from lhf_hf.utils.outputs import (  # deferred: heavy (pyarrow, via utils.io)
        COMPLETED,
        DISCARDED,
        PUSHES,
    )

    said = list(PUSHES)
    if COMPLETED:
        said.append("after it completed " + ", ".join(f"the {k} {p}" for k, p in COMPLETED))
    for kind, path, removed in DISCARDED:
        what = f"{path} is removed" if removed else f"{path} is empty again"
        said.append(f"before the {kind} held anything to resume: {what}; run the command again")
    return f" ({'; '.join(said)})" if said else ""


#: What the machine refuses (a full disk, a name too long, no permission), not a bug of ours: one
#: line.  Other OSErrors keep their traceback.
_MACHINE_ERRNOS = frozenset(
    {errno.ENOSPC, errno.EDQUOT, errno.ENAMETOOLONG, errno.EACCES, errno.EPERM, errno.EROFS}
)


if __name__ == "__main__":
    sys.exit(main())
