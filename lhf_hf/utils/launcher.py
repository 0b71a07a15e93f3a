"""The end of a run under a launcher (``accelerate launch`` / torchrun): one rule for every
command that runs on several ranks (``collect``, ``train``)."""

from __future__ import annotations

import os

from lhf_hf.errors import UserRuntimeError


def end_ranks() -> None:
    """Every rank waits for the others, then the process group is unregistered
    (``destroy_process_group``, as torch asks before exit).  One process: nothing to do.

    Without this a rank that was done exited while rank 0 still wrote, and could abort in
    interpreter shutdown (CI: "terminate called without an active exception", SIGABRT, after which
    the launcher killed rank 0 mid-write) or deadlock (seen here: the main thread, holding the GIL,
    joined gloo's worker threads in the group's destructor while one of them released a
    collective's work, whose tensors need the GIL to be freed).  The barrier is what makes exit
    safe: once every rank has passed it no collective is in flight, and a barrier's own work holds
    no Python tensor.  A DDP reducer keeps the group object alive, so its threads are still joined
    at exit, with nothing left to release."""
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1:
        return  # before PartialState(): a bare one would set accelerate's shared state up
    from accelerate import PartialState  # deferred: 1.4 s, needed under a launcher only

    state = PartialState()  # the shared state the Trainer or the collection set up
    wait_for_ranks(state)
    state.destroy_process_group()


def wait_for_ranks(state) -> None:
    """``state.wait_for_everyone()`` (an accelerate ``PartialState``), saying what it means when
    another rank is gone.  A rank that failed exits with its own error; the ranks waiting for it
    then got gloo's "Connection closed by peer [127.0.0.1]:PORT ..." as their only line, which
    reads as a network fault rather than as the other rank's error."""
    try:
        state.wait_for_everyone()
    except RuntimeError as exc:  # torch.distributed.DistBackendError is one
        raise UserRuntimeError(
            f"rank {state.process_index} of {state.num_processes}: another rank stopped before "
            f"reaching this point (its own error is printed above)"
        ) from exc
