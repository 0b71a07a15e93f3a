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
