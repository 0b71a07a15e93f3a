"""Runs under a launcher (``accelerate launch`` / torchrun): the shipped accelerate config, the
check that the launcher started the processes it was asked for, and the end of a run (one rule for
every command that runs on several ranks: ``collect``, ``train``)."""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path

from lhf_hf.errors import NotFoundError, UserRuntimeError

#: ``lhf_hf/launch``: accelerate configs shipped as package data (``lhf accelerate-config``).
LAUNCH_CONFIGS = Path(__file__).resolve().parents[1] / "launch"
#: CPU data parallelism, 2 processes on one machine (gloo): ``accelerate launch --config_file``.
CPU_2PROC = "cpu_2proc.yaml"


def accelerate_config(name: str = CPU_2PROC) -> Path:
    """The path of a shipped accelerate config (a wheel install has it as a checkout does)."""
    path = LAUNCH_CONFIGS / name
    if not path.is_file():
        raise NotFoundError(
            f"accelerate config {path} is missing: the lhf_hf install is incomplete (reinstall it)"
        )
    return path


#: Where MPI launchers (``accelerate launch --mpirun_hostfile``) put the world size.
_MPI_SIZES = ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE", "MV2_COMM_SIZE")


def launch_mismatch(environ: Mapping[str, str] = os.environ) -> str | None:
    """Why this process runs alone although ``accelerate launch`` was asked for more (None: it
    was not).

    ``accelerate launch --cpu --num_processes 2`` (or a ``MULTI_CPU`` config) uses accelerate's
    *simple* launcher, which starts ONE process: it sets ``ACCELERATE_USE_CPU`` and, for more than
    one process, ``MASTER_ADDR`` / ``MASTER_PORT``, but no ``WORLD_SIZE`` (torchrun's, which the
    MULTI_GPU launcher with ``use_cpu`` sets; ``accelerate/commands/launch.py``, ``launch_command``
    and ``utils/launch.py``, ``prepare_simple_launcher_cmd_env``).  The count asked for is read from
    the launcher's command line where the system shows it (Linux ``/proc``)."""
    if "ACCELERATE_USE_CPU" not in environ or "MASTER_PORT" not in environ:
        return None  # not accelerate's simple launcher, or one process asked for
    if "WORLD_SIZE" in environ or any(k in environ for k in _MPI_SIZES):
        return None  # a launcher that started the processes (torchrun, mpirun)
    asked = _asked_processes(_parent_command_line())
    if asked is not None and asked <= 1:
        return None  # MASTER_PORT was the user's own
    return (
        f"accelerate launch was asked for {asked or 'more than one'} processes but started this "
        "one alone (with --cpu or a MULTI_CPU config its simple launcher runs one process and "
        "sets no WORLD_SIZE): this runs as ONE process. For CPU data parallelism: accelerate "
        'launch --config_file "$(lhf accelerate-config)" [--num_processes N] -m lhf_hf ...'
    )


def _parent_command_line() -> list[str]:
    try:
        raw = Path(f"/proc/{os.getppid()}/cmdline").read_bytes()
    except OSError:  # not Linux, or not readable: the count stays unknown
        return []
    return raw.decode(errors="replace").split("\0")


def _asked_processes(argv: list[str]) -> int | None:
    """``--num_processes N`` (or ``--num-processes``, ``=N``) of an ``accelerate launch`` command
    line; None where it is not there (e.g. from a config file)."""
    for i, arg in enumerate(argv):
        m = re.fullmatch(r"--num[_-]processes(?:=(\d+))?", arg)
        if m:
            value = m.group(1) or (argv[i + 1] if i + 1 < len(argv) else "")
            return int(value) if value.isdigit() else None
    return None


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
