"""One stage of a reproduction in its own process (``lhf reproduce --jobs J``, ``parallel.py``).

    python -m lhf_hf.reproduce.worker EXPERIMENT PRESET --runs R --work WORK --stage HASH [--no-progress]

Plans the experiment exactly as the parent did (the plan is a function of the spec, preset, runs
and work folder) and runs the stage whose hash is HASH with the same ``StageRunner``, so the stage
is marked done the same way.  Torch gets the thread count of ``OMP_NUM_THREADS`` (the parent sets
1).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from contextlib import nullcontext
from pathlib import Path

import torch

from lhf_hf.utils.progress import library_bars
from lhf_hf.utils.signals import interrupts_raise_once, sigterm_raises

from .experiment import load_experiment
from .reproduce import plan_stages
from .stages import StageRunner


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m lhf_hf.reproduce.worker")
    p.add_argument("experiment")
    p.add_argument("preset")
    p.add_argument("--runs", type=int, required=True)
    p.add_argument("--work", required=True)
    p.add_argument("--stage", required=True, help="the stage's full config hash")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bars")
    a = p.parse_args(argv)
    if "OMP_NUM_THREADS" in os.environ:
        torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))
    exp = load_experiment(a.experiment, a.preset, a.runs)
    stages, _ = plan_stages(exp, Path(a.work), a.progress)
    match = [s for s in stages if s.hash == a.stage]
    if not match:
        print(f"no stage {a.stage} in {exp.name} at preset {a.preset}", file=sys.stderr)
        return 2
    # The parent stops a running stage with terminate() (SIGTERM): raised as an exception, the
    # stage unwinds as under Ctrl-C (its output folder put back or left resumable, its collection
    # workers stopped) instead of dying mid-write.  As a process of its own, the stage leaves
    # Ctrl-C, which reaches the whole process group, to the parent (whose terminate() follows):
    # it unwinds once, not again at each press (a repeated Ctrl-C cut its cleanup short).
    program = argv is None
    if program:
        interrupts_raise_once()
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    with nullcontext() if program else sigterm_raises(), library_bars(a.progress):
        StageRunner(a.work, echo=print).run(match[0])
    return 0


if __name__ == "__main__":
    sys.exit(main())
