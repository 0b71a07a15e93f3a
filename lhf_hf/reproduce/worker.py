"""One stage in its own process (``--jobs J``, ``parallel.py``): plans the experiment as the parent
did and runs the stage of hash HASH with the same ``StageRunner``, so it is marked done the same
way.  Torch takes its thread count from ``OMP_NUM_THREADS`` (the parent sets 1).

    python -m lhf_hf.reproduce.worker EXPERIMENT PRESET --runs R --work WORK --stage HASH [--no-progress]
"""

from __future__ import annotations

import argparse
import signal
import sys
from contextlib import nullcontext
from pathlib import Path

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
    exp = load_experiment(a.experiment, a.preset, a.runs)
    stages, _ = plan_stages(exp, Path(a.work), a.progress)
    match = [s for s in stages if s.hash == a.stage]
    if not match:
        print(f"no stage {a.stage} in {exp.name} at preset {a.preset}", file=sys.stderr)
        return 2
    # The parent stops a stage with terminate(): raised, SIGTERM unwinds the stage as Ctrl-C would
    # (its output put back or left resumable).  Ctrl-C reaches the whole process group and is the
    # parent's to pass on, once: ignored here, so a held-down Ctrl-C cannot cut a cleanup short.
    program = argv is None
    if program:
        interrupts_raise_once()
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    with nullcontext() if program else sigterm_raises(), library_bars(a.progress):
        StageRunner(a.work, echo=print).run(match[0])
    return 0


if __name__ == "__main__":
    sys.exit(main())
