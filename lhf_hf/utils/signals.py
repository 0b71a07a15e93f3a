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
    """From now on, this process ignores SIGINT and SIGTERM (main thread only: elsewhere a handler
    cannot be set, and Python runs handlers in the main thread)."""
    if threading.current_thread() is threading.main_thread():
        for sig in INTERRUPTS:
            signal.signal(sig, signal.SIG_IGN)


@contextmanager
def interrupts_ignored() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM are ignored (main thread only, as above; elsewhere no
    handler runs anyway); the previous handlers are restored.  For a cleanup that must not be cut
    short, e.g. stopping worker processes or waiting for native threads."""
    held = {}
    if threading.current_thread() is threading.main_thread():
        held = {sig: signal.signal(sig, signal.SIG_IGN) for sig in INTERRUPTS}
    try:
        yield
    finally:
        for sig, handler in held.items():
            signal.signal(sig, handler)


@contextmanager
def interrupts_held() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM wait: one that arrives is delivered (to the handler
    before the block) once the block is done.  For a step that must complete, after which the
    interrupt still stops the program: the switch from an old artifact to its new one."""
    got: list[int] = []
    held = {}
    if threading.current_thread() is threading.main_thread():
        held = {sig: signal.signal(sig, lambda s, f: got.append(s)) for sig in INTERRUPTS}
    try:
        yield
    finally:
        for sig, handler in held.items():
            signal.signal(sig, handler)
        if got:
            signal.raise_signal(got[0])


#: The signal that interrupted this program (``interrupts_raise_once``), once one has.
_received: list[int] = []


def interrupted_by() -> int | None:
    """The signal number that interrupted this program, or None.  A library may turn the
    KeyboardInterrupt into another error (transformers' lazy imports raise "Could not import
    module"); the program still ended because of the interrupt, and says so."""
    return _received[0] if _received else None


def _raise_once(signum, frame) -> None:
    _received.append(signum)
    ignore_interrupts()
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(128 + signum)


def interrupts_raise_once() -> None:
    """For a program's entry (``lhf``, a ``lhf reproduce`` stage process): the first SIGINT raises
    KeyboardInterrupt, the first SIGTERM ``Terminated``, and from then on both are ignored until the
    process ends.  The cleanup the first one starts (workers stopped, output folders put back,
    child stages waited for) then runs whole: a repeated Ctrl-C cut it short (a stage's folder
    removed or left half put back), and one landing in the interpreter's exit, which puts SIGINT's
    default action back first, killed the process after its cleanup (exit -2, not 130).  Not
    undone: for a process that ends with its command, never for a library call."""
    if threading.current_thread() is threading.main_thread():
        for sig in INTERRUPTS:
            signal.signal(sig, _raise_once)
