"""Run a C++ kernel's entry point over ``[0, n)`` in contiguous pieces on a thread pool (the PPO
kernel's learners, the attention kernel's (batch, head) pairs); ctypes releases the GIL for each
call's duration.

Why pieces, not one range per thread: a thread that loses its core for a while (the collector
writes the previous chunk in the background, other processes run) would leave the others waiting
at the end of a static split; with several pieces per thread the idle ones take its share.
Results do not depend on the split.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor, wait

from .signals import interrupts_ignored


@functools.cache
def _pool(threads: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(threads, thread_name_prefix="lhf-kernel")


def run_pieces(
    fn: Callable,
    ref,
    n: int,
    threads: int,
    pieces_per_thread: int,
    what: str,
    errors: dict[int, str],
) -> None:
    """``fn(ref, i0, i1)`` over ``[0, n)``, ``pieces_per_thread`` pieces per thread, ``threads``
    threads; a non-zero return code raises, named by ``errors`` (``what``: the kernel's name)."""
    threads = max(1, min(threads, n))
    if threads == 1:
        codes = [fn(ref, 0, n)]
    else:
        pieces = min(n, threads * pieces_per_thread)
        bounds = [n * i // pieces for i in range(pieces + 1)]
        futures = [_pool(threads).submit(fn, ref, bounds[i], bounds[i + 1]) for i in range(pieces)]
        try:
            codes = [f.result() for f in futures]
        except BaseException:
            _settle(futures)
            raise
    for code in codes:
        if code != 0:
            raise RuntimeError(f"the {what} failed: {errors.get(code, code)}")


def _settle(futures: list[Future]) -> None:
    """Interrupted (Ctrl-C) while the pieces run: drop the queued ones and wait for the running
    ones before the caller unwinds.  A running piece reads and writes, through raw pointers, the
    tensors the unwinding frees (and the interpreter's exit tears down): an interrupted batched
    collection crashed with a segfault in the kernel after printing "interrupted".  A piece takes
    milliseconds; a further interrupt meanwhile is ignored."""
    with interrupts_ignored():
        for f in futures:
            f.cancel()
        wait(futures)
