"""The program's entry (the ``lhf`` console script and ``python -m lhf_hf``): Ctrl-C or SIGTERM
while the commands are still being imported ends the program quietly, with 130 / 143.

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
        code = main()  # installs the command's own handling first, ignores interrupts at its end
    except BrokenPipeError:
        # the reader of our output went away (`lhf envs --json | head`): end quietly, as a
        # shell tool killed by SIGPIPE would (Python's own advice: no more writes to stdout)
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
