"""``lhf`` as a program (``python -m lhf_hf``) that says at exit whether this rank's process group
is still alive: tests launch it with ``accelerate launch`` to check that every rank destroyed the
group before exiting (torch requires it; a gloo group left to interpreter shutdown can abort or
deadlock the rank, see ``utils.launcher.end_ranks``).

``LHF_PROBE_FAIL_RANK=R``: rank R's collector raises after 3 s instead of collecting (the other
ranks are then waiting for it at the end of their share)."""

import atexit
import importlib
import os
import sys
import time

import torch.distributed as dist

from lhf_hf.cli.main import main
from lhf_hf.errors import UserError


def _report() -> None:
    alive = dist.is_available() and dist.is_initialized()
    print(f"rank {os.environ.get('RANK')}: process group alive at exit: {alive}", file=sys.stderr)


def _failing(config, out, tasks, ranks, progress) -> None:
    time.sleep(3)  # the other ranks finish their share and wait at the barrier
    raise UserError(f"probe: rank {ranks.rank} fails")  # an expected failure: one line


if os.environ.get("LHF_PROBE_FAIL_RANK") == os.environ.get("RANK"):
    driver = importlib.import_module("lhf_hf.collection.driver")
    driver.RUNNERS = {name: _failing for name in driver.RUNNERS}

atexit.register(_report)  # registered first: runs after everything registered later
sys.exit(main())
