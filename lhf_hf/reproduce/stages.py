"""Stages cached by their config's hash (docs/reproduce.md, ``stages.py``): a stage's folder is
``WORK/<kind>/<hash12>``, the hash covering its config and the hashes of the stages it reads, and
``stage.json``, written last, marks it done; an unfinished stage is resumed by its own function.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from lhf_hf.collection.backend_verdict import cpu_model
from lhf_hf.utils.io import read_json, write_json_atomic

DONE_FILE = "stage.json"
LOG_FILE = "stage.log"  # a child process's output (``parallel.py``)
#: The wall time of a stage finished on another machine (``portable.py``), for the report.
RECORD_FILE = "stage.record.json"


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


def _seconds(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and 0 <= v < float("inf")


def done_record(folder: Path) -> dict | None:
    """A stage folder's ``stage.json`` when it is that stage's record: an object with ``wall_s``
    >= 0 whose ``kind`` and ``config`` hash to the folder's name.  Anything else (a hand edit, a
    truncated copy, another stage's record) is None: the stage runs again and resumes."""
    folder = Path(folder)
    try:
        found = read_json(folder / DONE_FILE)
    except (OSError, ValueError):
        return None
    if not isinstance(found, dict) or not _seconds(found.get("wall_s")):
        return None
    kind, config = found.get("kind"), found.get("config")
    if not isinstance(kind, str) or not isinstance(config, dict) or kind != folder.parent.name:
        return None
    return found if config_hash({"kind": kind, **config})[:12] == folder.name else None


class StageRunner:
    """Runs stages one by one, a numbered line each; ``log`` lists what ran and what was cached."""

    def __init__(self, work: str | Path, total: int | None = None, echo: Callable = print):
        self.work = Path(work)
        self.total = total
        self.done = 0
        self.echo = echo
        self.log: list[dict] = []

    def head(self, stage: Stage) -> str:
        """The next stage's numbered line."""
        self.done += 1
        return f"[{self.done}/{self.total or '?'}] {stage.kind:<8} {stage.label}"

    def record(self, stage: Stage, wall: float | None = None) -> None:
        """``log`` the stage: cached (no ``wall``), or run in ``wall`` seconds."""
        entry = {"stage": stage.label, "path": str(stage.path(self.work)), "cached": wall is None}
        self.log.append(entry if wall is None else {**entry, "wall_s": wall})

    def run(self, stage: Stage) -> Path:
        out = stage.path(self.work)
        head = self.head(stage)
        if stage.done(self.work):
            self.echo(f"{head}: cached ({out})")
            self.record(stage)
            return out
        self.echo(f"{head} ...")
        # an earlier, interrupted call left something: the stage resumes, so its wall time covers
        # only part of its work and is no rate for later estimates
        resumed = out.is_dir() and any(p.name not in (LOG_FILE, RECORD_FILE) for p in out.iterdir())
        t0 = time.perf_counter()
        out.mkdir(parents=True, exist_ok=True)
        stage.fn(out)
        wall = round(time.perf_counter() - t0, 1)
        done = {"kind": stage.kind, "label": stage.label, "config": stage.config, "wall_s": wall}
        done["resumed"] = resumed
        if stage.cost is not None:  # a measured rate for later estimates (``estimate.py``)
            done.update(cost=dataclasses.asdict(stage.cost), cpu=cpu_model())
        write_json_atomic(done, out / DONE_FILE)
        self.echo(f"{head}: done in {wall} s")
        self.record(stage, wall)
        return out


def needed_stages(
    stages: list[Stage],
    work: Path,
    targets: list[Stage],
    done: Callable[[Stage], bool] | None = None,
) -> list[Stage]:
    """``stages`` (in plan order) less those not done that no needed stage reads: a stage is
    needed when it is a target (what the report reads) or a needed stage not done reads it, so a
    training whose evaluations were imported is left out.  ``done``: what counts as done (default:
    finished under ``work``)."""
    is_done = done or (lambda s: s.done(Path(work)))
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
    """The wall time a finished stage recorded, here or in an imported record (else 0)."""
    for name in (DONE_FILE, RECORD_FILE):
        try:
            wall = read_json(Path(folder) / name).get("wall_s")
        except (OSError, ValueError, AttributeError):
            continue
        if _seconds(wall):
            return float(wall)
    return 0.0
