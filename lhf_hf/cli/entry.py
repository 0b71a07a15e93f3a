"""The program's entry (the ``lhf`` console script and ``python -m lhf_hf``): Ctrl-C or SIGTERM
while the commands are still being imported ends the program quietly, with 130 / 143; a closed
pipe on stdout, whichever command (or ``--help``) wrote, ends it quietly with 141.

``lhf_hf.cli.main`` imports every command's config (numpy, gymnasium: ~0.4 s) before ``main``
installs its interrupt handling; an interrupt in that window raised KeyboardInterrupt inside an
import and printed its traceback.  Nothing has been written then, so ending at once loses nothing.
"""

from __future__ import annotations

import os
import signal
import sys


def _quit_while_starting(signum, frame) -> None:
    sys.stderr.write(f"lhf: {'terminated' if signum == signal.SIGTERM else 'interrupted'}\n")
    sys.stderr.flush()
    os._exit(128 + signum)  # only imports have run: nothing to clean up


def run() -> None:
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _quit_while_starting)
    from lhf_hf.cli.main import main  # deferred: after the handlers (the point of this module)

    try:
        try:
            code = main()  # installs the command's own handling, ignores interrupts at its end
        except SystemExit as exc:  # argparse: --help, --version, a usage error
            if not (exc.code is None or isinstance(exc.code, int)):
                raise
            code = exc.code or 0
        # What is still buffered (argparse's help and version are written, not flushed): flushed
        # here, where a closed pipe can be caught, not by the interpreter's exit ("Exception
        # ignored ... BrokenPipeError", status 120).
        sys.stdout.flush()
    except BrokenPipeError:
        # The reader of our output went away (`lhf envs --json | head -1`, `lhf --help | head`):
        # end quietly with the status of a shell tool killed by SIGPIPE.  As the Python docs'
        # "Note on SIGPIPE" advises: stdout goes to devnull, so that the exit's flush cannot
        # fail again, and SIGPIPE keeps Python's disposition (SIG_DFL would also kill the
        # program on a closed socket).
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        code = 128 + signal.SIGPIPE
    if code in (128 + signal.SIGINT, 128 + signal.SIGTERM):
        # Interrupted, and cleaned up already.  A KeyboardInterrupt that landed inside code run by
        # PyRun_* (e.g. during torch's import) sets CPython's "unhandled KeyboardInterrupt" flag
        # even when we caught it, and the interpreter's exit then kills the process with SIGINT
        # (-2, not 130): end here instead, with the status the message gave.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)
