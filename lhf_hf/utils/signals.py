"""SIGTERM as an exception, so that a command stopped by ``kill``, ``timeout`` or ``docker stop``
cleans up like after Ctrl-C: output folders put back or left resumable (``utils.outputs``),
worker pools stopped, locks released.  Python's default SIGTERM ends the process at once, with
no ``finally`` run."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager


class Terminated(SystemExit):
    """Raised by SIGTERM inside ``sigterm_raises``; its code is 128 + SIGTERM, as a shell's."""


def _terminate(signum, frame) -> None:
    raise Terminated(128 + signum)


@contextmanager
def sigterm_raises() -> Iterator[None]:
    """Within the block, SIGTERM raises ``Terminated`` in the main thread (elsewhere a handler
    cannot be installed: the block then changes nothing); the previous handler is restored."""
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


#: What stops a command: Ctrl-C and ``kill`` / ``timeout``.
INTERRUPTS = (signal.SIGINT, signal.SIGTERM)


def ignore_interrupts() -> None:
    """From now on, this process ignores SIGINT and SIGTERM: for a program that has handled an
    interrupt and is exiting.  The interpreter's exit puts SIGINT's default action back before it
    ends, and a torch-sized exit takes long enough for the second press of a double Ctrl-C to land
    there: the process was killed by the signal (exit -2, not 130) after its cleanup had run."""
    if threading.current_thread() is threading.main_thread():
        for sig in INTERRUPTS:
            signal.signal(sig, signal.SIG_IGN)
