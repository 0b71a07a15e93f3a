"""``lhf`` as a program (``python -m lhf_hf``) that says at exit whether this rank's process group
is still alive: tests launch it with ``accelerate launch`` to check that every rank destroyed the
group before exiting (torch requires it; a gloo group left to interpreter shutdown can abort or
deadlock the rank, see ``utils.launcher.end_ranks``)."""

import atexit
import os
import sys

import torch.distributed as dist

from lhf_hf.cli.main import main


def _report() -> None:
    alive = dist.is_available() and dist.is_initialized()
    print(f"rank {os.environ.get('RANK')}: process group alive at exit: {alive}", file=sys.stderr)


atexit.register(_report)  # registered first: runs after everything registered later
sys.exit(main())
