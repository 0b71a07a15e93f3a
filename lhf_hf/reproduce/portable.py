"""Finished stages carried to another machine: ``lhf reproduce --export-stages`` / ``--import-stages``.

A table at the ``cpu`` budget can take longer than one machine is held (the main table's DICP cells:
~3 h wall on 2 cores), and the stage cache (datasets, checkpoints: gigabytes, git-ignored) does not
travel.  What a report reads is small: each evaluation's returns (~0.1 MB per evaluate stage).  So
an export copies, for every finished stage of the plan:

- ``evaluate`` stages whole (``evaluate/<hash12>/``, ``stage.json`` included, ``stage.log`` left out);
- of every other stage only its ``stage.json`` (``records/<kind>-<hash12>.json``): what it cost,
  for the report's stage time.  Collections, filters and trainings are not carried: a filter is
  recomputed from its collection in seconds, and a training is not needed once its evaluations are
  (``stages.needed_stages``).

``stages.json`` lists them.  An import checks that each stage's recorded config hashes to its name
(the same hash the plan computes, so a stage of another experiment, preset or code version simply
matches nothing), copies the evaluations that are not done in the work folder (atomically: a copy
beside it, then a rename), and writes the records as ``stage.record.json``.  A later call with the
same command then runs only what is left: the other runs' stages, and the collections and filters
the report reads.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from lhf_hf.utils.io import write_json_atomic
from lhf_hf.utils.outputs import output_folder

from .stages import DONE_FILE, LOG_FILE, RECORD_FILE, Stage, config_hash

#: Kinds of stage carried whole: small outputs that cost minutes to hours to make again.
PORTABLE = ("evaluate",)
INDEX_FILE = "stages.json"
FORMAT = 1


def _identity(done: dict) -> str:
    """The hash a finished stage's ``stage.json`` names: that of its kind and config."""
    return config_hash({"kind": done["kind"], **done["config"]})


def export_stages(stages: list[Stage], work: str | Path, dest: str | Path, about: dict) -> dict:
    """Copy the finished stages of ``stages`` from ``work`` into ``dest`` (an lhf ``stages``
    folder, replaced when it is one already); ``about`` (the command) goes into ``stages.json``.
    Returns the counts: ``{"portable": n, "records": n, "not_done": n}``."""
    work, dest = Path(work), Path(dest)
    entries, not_done = [], 0
    with output_folder(dest, "stages", overwrite=True, inputs=[work]) as out:
        for s in stages:
            src = s.path(work)
            if not s.done(work):
                not_done += 1
                continue
            entry = {"kind": s.kind, "label": s.label, "hash": s.hash}
            if s.kind in PORTABLE:
                target = out / s.kind / src.name
                shutil.copytree(src, target, ignore=shutil.ignore_patterns(LOG_FILE, ".*.lock"))
                entry["path"] = f"{s.kind}/{src.name}"
            else:
                record = json.loads((src / DONE_FILE).read_text())
                entry["path"] = f"records/{s.kind}-{src.name}.json"
                write_json_atomic(record, out / entry["path"])
            entries.append(entry)
        write_json_atomic({"format": FORMAT, **about, "stages": entries}, out / INDEX_FILE)
    portable = sum(e["kind"] in PORTABLE for e in entries)
    return {"portable": portable, "records": len(entries) - portable, "not_done": not_done}


def import_stages(src: str | Path, work: str | Path, plan: list[Stage]) -> dict:
    """Copy the stages exported to ``src`` into ``work`` (those not done there already).

    Returns the counts: ``{"imported": n, "records": n, "present": n, "in_plan": n, "total": n}``
    (``in_plan``: how many of them this plan has: 0 means another experiment, preset, run count
    or code version).  Raises ``ValueError`` on a folder that is not an export, or a stage whose
    recorded config does not hash to its name (edited or damaged)."""
    src, work = Path(src), Path(work)
    index_path = src / INDEX_FILE
    if not index_path.is_file():
        raise ValueError(
            f"{src} is not an export of finished stages (no {INDEX_FILE}; "
            "make one with lhf reproduce ... --export-stages DIR)"
        )
    try:
        index = json.loads(index_path.read_text())
        entries = index["stages"]
        if index.get("format") != FORMAT:
            raise ValueError(f"format {index.get('format')!r}, this version reads {FORMAT}")
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{index_path} is unreadable: {exc}") from exc
    planned = {s.hash: s for s in plan}
    counts = {"imported": 0, "records": 0, "present": 0, "in_plan": 0, "total": len(entries)}
    for e in entries:
        path = src / e["path"]
        try:
            done = json.loads((path / DONE_FILE if e["kind"] in PORTABLE else path).read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"{src}: stage {e['label']!r} is unreadable: {exc}") from exc
        if done.get("kind") != e["kind"] or _identity(done) != e["hash"]:
            raise ValueError(
                f"{src}: stage {e['label']!r} ({e['path']}) does not match its recorded config "
                "(edited or damaged): nothing more was imported"
            )
        counts["in_plan"] += e["hash"] in planned
        target = work / e["kind"] / e["hash"][:12]
        if (target / DONE_FILE).exists():
            counts["present"] += 1
            continue
        if e["kind"] in PORTABLE:
            _copy_in(path, target)
            counts["imported"] += 1
        else:
            target.mkdir(parents=True, exist_ok=True)
            write_json_atomic(done, target / RECORD_FILE)
            counts["records"] += 1
    return counts


def _copy_in(path: Path, target: Path) -> None:
    """``path`` becomes ``target`` whole or not at all: a copy beside it, then a rename; what an
    interrupted stage left there (it resumes nothing an import replaces) is removed after."""
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.parent / f".{target.name}.importing-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    shutil.copytree(path, tmp)
    old = None
    if target.exists():
        old = target.parent / f".{target.name}.replaced-{os.getpid()}"
        os.replace(target, old)
    os.replace(tmp, target)
    if old is not None:
        shutil.rmtree(old)
