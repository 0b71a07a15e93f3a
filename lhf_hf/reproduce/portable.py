"""``--export-stages DIR`` / ``--import-stages DIR`` (docs/reproduce.md, ``portable.py``): a plan's
finished evaluations (~0.1 MB each; datasets and checkpoints never travel) and the wall times of
its other finished stages, carried to another machine, checked whole before anything is copied.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

from lhf_hf.errors import UserError
from lhf_hf.utils.io import read_json, sha256_file, write_json_atomic
from lhf_hf.utils.outputs import output_folder

from .stages import DONE_FILE, LOG_FILE, RECORD_FILE, Stage, config_hash, stage_wall

INDEX_FILE = "stages.json"
FORMAT = 2


class ExportError(UserError):
    """An export that cannot be written or read as asked."""


def _files(folder: Path) -> dict[str, str]:
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    return {p.relative_to(folder).as_posix(): sha256_file(p) for p in files}


def _entry(s: Stage, **more) -> dict:
    return {"kind": s.kind, "label": s.label, "hash": s.hash, **more}


def export_stages(stages: list[Stage], work: str | Path, dest: str | Path, about: dict) -> dict:
    """Copy the plan's finished evaluations from ``work`` into ``dest`` (new, or an earlier export
    that holds no evaluation they lack); ``about`` goes into ``stages.json``.  Returns the counts
    ``{"portable", "records", "not_done"}``."""
    work, dest = Path(work), Path(dest)
    if not work.is_dir():
        raise ExportError(f"the work folder {work} does not exist: nothing to export")
    evals = [s for s in stages if s.kind == "evaluate" and s.done(work)]
    if not evals:
        raise ExportError(f"no evaluation of this plan is finished in {work}: nothing to export")
    if dest.resolve().is_relative_to(work.resolve()):
        raise ExportError(f"{dest} is inside the work folder {work}: export somewhere else")
    if (dest / INDEX_FILE).is_file():
        try:
            old = {e["hash"] for e in read_json(dest / INDEX_FILE)["stages"]}
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ExportError(
                f"{dest} holds an export whose index cannot be read ({exc})"
            ) from None
        if lost := old - {s.hash for s in evals}:
            raise ExportError(f"{dest} holds {len(lost)} evaluation(s) this export would not")
    entries = []
    # an lhf output folder (``lhf verify`` checks it); someone's folder is refused, not replaced
    with output_folder(
        dest, "stages", overwrite=True, inputs=[work], own_nested=["evaluation"]
    ) as out:
        for s in evals:
            path = f"evaluate/{s.hash[:12]}"
            ignore = shutil.ignore_patterns(LOG_FILE, ".*.lock")
            shutil.copytree(s.path(work), out / path, ignore=ignore)
            entries.append(_entry(s, path=path, files=_files(out / path)))
        records = [
            _entry(s, wall_s=wall)
            for s in stages
            if s.kind != "evaluate" and (wall := stage_wall(s.path(work)))
        ]
        index = {"format": FORMAT, **about, "stages": entries, "records": records}
        write_json_atomic(index, out / INDEX_FILE)
    not_done = len(stages) - len(entries) - len(records)
    return {"portable": len(entries), "records": len(records), "not_done": not_done}


def check_export(src: str | Path) -> list[str]:
    """What is wrong with an export (``lhf verify``, and each import first); empty when none:
    every file's checksum, each stage's recorded config hashing to its name, its path of the form
    ``evaluate/<hash12>``."""
    src = Path(src)
    try:
        index = read_json(src / INDEX_FILE)
        if index.get("format") != FORMAT:
            return [f"{src}: format {index.get('format')!r}, this version reads {FORMAT}"]
        entries = [(e["label"], e["hash"], e["path"], e["files"]) for e in index["stages"]]
    except (OSError, ValueError, AttributeError, KeyError, TypeError) as exc:
        return [f"{src} is no readable export of finished stages ({INDEX_FILE}): {exc!r}"]
    problems = []
    for label, h, path, files in entries:
        folder = src / path
        inside = re.fullmatch("[0-9a-f]{64}", str(h)) and path == f"evaluate/{h[:12]}"
        if not inside or not folder.is_dir() or _files(folder) != files:
            problems.append(f"{src}: stage {label!r} ({path}) changed since it was exported")
            continue
        try:
            config = read_json(folder / DONE_FILE)["config"]
            matches = config_hash({"kind": "evaluate", **config}) == h
        except (OSError, ValueError, KeyError, TypeError):  # no stage.json, or not a record
            matches = False
        if not matches:
            problems.append(f"{src}: stage {label!r} does not match its recorded config")
    return problems


def import_stages(src: str | Path, work: str | Path, plan: list[Stage]) -> dict:
    """Copy the evaluations of ``plan`` exported to ``src`` that are not done in ``work`` (a copy
    beside, then a rename; ``stage.json`` gains ``imported``), and the records of its other
    stages.  Returns the counts and ``about`` (what the export says of itself)."""
    src, work = Path(src), Path(work)
    if problems := check_export(src):
        raise ExportError(f"{problems[0]}: nothing was imported")
    index = read_json(src / INDEX_FILE)
    about = {k: v for k, v in index.items() if k not in ("stages", "records")}
    origin = {"from": str(src.resolve()), **{k: about.get(k) for k in ("created", "versions")}}
    planned = {s.hash: s for s in plan}
    n = {"imported": 0, "present": 0, "records": 0, "evaluations": len(index["stages"])}
    n.update(about=about, evaluations_in_plan=sum(e["hash"] in planned for e in index["stages"]))
    for e in index["stages"]:
        s = planned.get(e["hash"])
        if s is None or s.done(work):
            n["present"] += s is not None
            continue
        target = s.path(work)
        tmp = target.parent / f".{target.name}.importing-{os.getpid()}"
        shutil.copytree(src / e["path"], tmp)
        write_json_atomic({**read_json(tmp / DONE_FILE), "imported": origin}, tmp / DONE_FILE)
        shutil.rmtree(target, ignore_errors=True)  # what an interrupted stage left
        os.replace(tmp, target)
        n["imported"] += 1
    for r in index.get("records", []):
        s = planned.get(r["hash"])
        if s is not None and not s.done(work) and not (s.path(work) / RECORD_FILE).exists():
            s.path(work).mkdir(parents=True, exist_ok=True)
            write_json_atomic(r, s.path(work) / RECORD_FILE)
            n["records"] += 1
    return n
