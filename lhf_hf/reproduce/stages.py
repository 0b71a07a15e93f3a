"""Stages cached by their config's hash: a rerun skips what is done and resumes what is not.

A stage's folder is ``WORK/<kind>/<hash12>`` where the hash covers the stage's own config AND the
hashes of the stages it reads (its ``inputs``), so changing a collection setting re-runs everything
downstream of it and nothing else.  ``stage.json`` is written last (atomically): its presence is
the "done" mark.  A half-finished stage is resumed by the stage function itself (collection and
training resume from their own markers/checkpoints).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch

from lhf_hf.collection.backend_verdict import cpu_model, instruction_set
from lhf_hf.utils.io import read_json, write_json_atomic

DONE_FILE = "stage.json"
LOG_FILE = "stage.log"  # a child process's output (``parallel.py``)
#: A finished stage's ``stage.json`` imported without its output (``portable.py``): what it cost,
#: for the report's stage time; the stage itself is not done here.
RECORD_FILE = "stage.record.json"
#: A ``stage.json`` cost's key format: 2 = keys name a non-default model context (``|ctxN``,
#: ``rate_key.RateKey``); records without it are re-keyed when read (``estimate.current_key``).
COST_FORMAT = 2
#: Said of a ``stage.json`` that is no finished stage's record (``done_record``).
NO_RECORD = "is no finished stage's record: running it again"


def config_hash(config: dict) -> str:
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()


@dataclass(frozen=True)
class Cost:
    """What a stage's time scales with: ``units`` of work of one ``key`` (``estimate.py``)."""

    key: str
    units: float


@dataclass
class Stage:
    kind: str  # collect / derive / filter / train / evaluate
    label: str  # human-readable, for the progress display
    config: dict  # everything that determines the output, upstream hashes included
    fn: Callable[[Path], None]  # writes the output into the folder it is given
    inputs: tuple[Stage, ...] = ()  # the stages whose folders it reads (run them first)
    cost: Cost | None = None  # for ``--estimate``; recorded with the wall time when done

    @property
    def hash(self) -> str:
        return config_hash({"kind": self.kind, **self.config})

    def path(self, work: Path) -> Path:
        return Path(work) / self.kind / self.hash[:12]

    def done(self, work: Path) -> bool:
        return done_record(self.path(work)) is not None


def finite_number(v) -> bool:
    """A finite JSON number: an int or float, not a bool, a string, NaN, infinity or an integer
    too large for a float (it would overflow when used as one)."""
    if not isinstance(v, int | float) or isinstance(v, bool):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


def finite_seconds(v) -> bool:
    """A JSON number of seconds: a ``finite_number`` >= 0."""
    return finite_number(v) and v >= 0


def done_record(folder: Path) -> dict | None:
    """A stage folder's ``stage.json`` when it is that stage's record: a JSON object with a finite
    ``wall_s`` >= 0 whose ``kind`` and ``config`` hash to the folder's own name
    (``WORK/<kind>/<hash12>``; every version of ``StageRunner`` wrote all three).  Anything else (a
    hand edit, ``[]``, a truncated copy, another stage's record) is None: the stage is not done
    and runs again (its function resumes from its own markers), rather than a report reading
    output that may not be there."""
    folder = Path(folder)
    try:
        found = read_json(folder / DONE_FILE)
    except (OSError, ValueError):
        return None
    if not isinstance(found, dict) or not finite_seconds(found.get("wall_s")):
        return None
    kind, config = found.get("kind"), found.get("config")
    if not isinstance(kind, str) or not isinstance(config, dict) or kind != folder.parent.name:
        return None
    return found if config_hash({"kind": kind, **config})[:12] == folder.name else None


class StageRunner:
    """Runs stages in order with a one-line-per-stage progress display."""

    def __init__(self, work: str | Path, total: int | None = None, echo: Callable = print):
        self.work = Path(work)
        self.total = total
        self.done = 0
        self.echo = echo
        self.log: list[dict] = []

    def run(self, stage: Stage) -> Path:
        out = stage.path(self.work)
        self.done += 1
        head = f"[{self.done}/{self.total or '?'}] {stage.kind:<8} {stage.label}"
        if stage.done(self.work):
            self.echo(f"{head}: cached ({out})")
            self.log.append({"stage": stage.label, "path": str(out), "cached": True})
            return out
        if (out / DONE_FILE).exists():  # written by hand or cut short: not this stage's mark
            self.echo(f"{head}: {out / DONE_FILE} {NO_RECORD}")
        self.echo(f"{head} ...")
        # Something of an earlier, interrupted call is here: the stage resumes, so its wall time
        # covers only part of its work and is no rate for later estimates.
        resumed = out.is_dir() and any(p.name not in (LOG_FILE, RECORD_FILE) for p in out.iterdir())
        t0 = time.perf_counter()
        out.mkdir(parents=True, exist_ok=True)
        stage.fn(out)
        wall = round(time.perf_counter() - t0, 1)
        done = {"kind": stage.kind, "label": stage.label, "config": stage.config, "wall_s": wall}
        if stage.cost is not None and not resumed:  # a measured rate for later estimates
            done.update(
                cost={**dataclasses.asdict(stage.cost), "format": COST_FORMAT},
                cpu=cpu_model(),
                isa=instruction_set(),  # "AMD EPYC" names machines ~2x apart (estimate.same_machine)
                threads=torch.get_num_threads(),
            )
        elif resumed:
            done["resumed"] = True
        write_json_atomic(done, out / DONE_FILE)
        self.echo(f"{head}: done in {wall} s")
        self.log.append({"stage": stage.label, "path": str(out), "cached": False, "wall_s": wall})
        return out


def needed_stages(
    stages: list[Stage],
    work: Path,
    targets: list[Stage],
    done: Callable[[Stage], bool] | None = None,
) -> list[Stage]:
    """``stages`` (in plan order) less those this call need not run: a stage not done is needed
    when it is a target (what the report reads) or some needed stage reads it.  A training whose
    evaluations are all done (imported from another machine's cache, ``portable.py``) is left out,
    and so is the collection only it read.  Done stages stay (they are reported as cached).
    ``done``: what counts as done (default: finished under ``work``; ``coverage.py`` counts the
    stages of a committed export)."""
    work = Path(work)
    is_done = done or (lambda s: s.done(work))
    needed: set[str] = set()
    todo = list(targets)
    while todo:
        s = todo.pop()
        if s.hash in needed:
            continue
        needed.add(s.hash)
        if not is_done(s):
            todo.extend(s.inputs)
    return [s for s in stages if s.hash in needed or is_done(s)]


def stage_wall(folder: Path) -> float:
    """The wall time a finished stage recorded, here or in an imported record (0 when none, or
    when what is there is no record: a table's stage time stays a number)."""
    found = done_record(folder)
    if found is None:
        try:
            found = json.loads((Path(folder) / RECORD_FILE).read_text())
        except (OSError, ValueError):
            return 0.0
    wall = found.get("wall_s") if isinstance(found, dict) else None
    return float(wall) if finite_seconds(wall) else 0.0
