"""Finished evaluations carried between machines: ``--export-stages DIR`` / ``--import-stages DIR``.

A table can take longer than one machine is held (or its trainings want a GPU), and the stage cache
(datasets, checkpoints) does not travel; all a report reads of a model is its evaluation (~0.1 MB).
An export copies every finished ``evaluate`` stage of the plan whole (``stage.log`` left out) and
lists in ``stages.json`` each one's files with their SHA-256, plus the wall time of the plan's
other finished stages (for the report's stage time).  An import checks the whole export first
(``check_export``: every file's checksum, each stage's config hashing to its name) and then copies
the evaluations of this plan not done here (a copy beside, then a rename; ``stage.json`` gains
``imported``); ``stages.needed_stages`` then leaves out the trainings only they read.
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
    return {p.relative_to(folder).as_posix(): sha256_file(p) for p in sorted(folder.rglob("*"))
            if p.is_file()}  # fmt: skip


def export_stages(stages: list[Stage], work: str | Path, dest: str | Path, about: dict) -> dict:
    """Copy the plan's finished evaluations from ``work`` into ``dest`` (new, or an earlier export,
    replaced); ``about`` goes into ``stages.json``.  Returns ``{"portable", "records", "not_done"}``."""
    work, dest = Path(work), Path(dest)
    if not work.is_dir():
        raise ExportError(f"the work folder {work} does not exist: nothing to export")
    evals = [s for s in stages if s.kind == "evaluate" and s.done(work)]
    if not evals:
        raise ExportError(f"no evaluation of this plan is finished in {work}: nothing to export")
    if dest.resolve().is_relative_to(work.resolve()):
        raise ExportError(f"{dest} is inside the work folder {work}: export somewhere else")
    if (dest / INDEX_FILE).is_file():  # an earlier export: replaced only by one holding it all
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
            shutil.copytree(
                s.path(work), out / path, ignore=shutil.ignore_patterns(LOG_FILE, ".*.lock")
            )
            entries.append({"kind": s.kind, "label": s.label, "hash": s.hash, "path": path,
                            "files": _files(out / path)})  # fmt: skip
        records = [{"kind": s.kind, "label": s.label, "hash": s.hash, "wall_s": wall}
                   for s in stages if s.kind != "evaluate" and (wall := stage_wall(s.path(work)))]  # fmt: skip
        index = {"format": FORMAT, **about, "stages": entries, "records": records}
        write_json_atomic(index, out / INDEX_FILE)
    return {"portable": len(entries), "records": len(records),
            "not_done": len(stages) - len(entries) - len(records)}  # fmt: skip


def check_export(src: str | Path) -> list[str]:
    """What is wrong with an export (``lhf verify``, and each import first); empty when none."""
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
        if not inside or not folder.is_dir() or _files(folder) != files:  # paths: of the export
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
    """Copy the evaluations of ``plan`` exported to ``src`` that are not done in ``work`` (and the
    records of its other stages).  Returns the counts and ``about`` (the export's command)."""
    src, work = Path(src), Path(work)
    problems = check_export(src)
    if problems:
        raise ExportError(f"{problems[0]}: nothing was imported")
    index = read_json(src / INDEX_FILE)
    about = {k: v for k, v in index.items() if k not in ("stages", "records")}
    origin = {"from": str(src.resolve()), "created": about.get("created"),
              "versions": about.get("versions")}  # fmt: skip
    planned = {s.hash: s for s in plan}
    n = {
        "imported": 0,
        "present": 0,
        "records": 0,
        "evaluations": len(index["stages"]),
        "about": about,
    }
    n["evaluations_in_plan"] = sum(e["hash"] in planned for e in index["stages"])
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
