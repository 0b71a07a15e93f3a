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

``stages.json`` lists them, with the SHA-256 of every file copied.  An import first checks the whole
export (known kinds, paths inside it, every file's checksum, each stage's recorded config hashing
to its name: the hash the plan computes) and only then copies: the evaluations of this plan that
are not done in the work folder (each atomically: a copy beside it, then a rename; its
``stage.json`` then names where it came from, for the report), and the records as
``stage.record.json``.  Stages of another experiment, preset or code version match nothing in the
plan and are not copied.  A later call with the same command then runs only what is left: the
other runs' stages, and the collections and filters the report reads.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

from lhf_hf.errors import UserError
from lhf_hf.utils.io import read_json, sha256_file, write_json_atomic
from lhf_hf.utils.outputs import check_manifest, output_folder

from .stages import DONE_FILE, LOG_FILE, RECORD_FILE, Stage, config_hash, done_record

#: Kinds of stage carried whole: small outputs that cost minutes to hours to make again.
PORTABLE = ("evaluate",)
#: Every kind a plan has (``reproduce.plan_stages``): an export naming another is refused.
KINDS = ("collect", "derive", "filter", "train", "evaluate")
INDEX_FILE = "stages.json"
FORMAT = 1
_HASH = re.compile(r"[0-9a-f]{64}")


class ExportError(UserError):
    """An export that cannot be written or read as asked (one clear line)."""


def _identity(done: dict) -> str:
    """The hash a finished stage's ``stage.json`` names: that of its kind and config."""
    return config_hash({"kind": done["kind"], **done["config"]})


def _files(folder: Path) -> dict[str, str]:
    """``{relative path: sha256}`` of every file under ``folder``."""
    return {
        p.relative_to(folder).as_posix(): sha256_file(p)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def read_index(src: str | Path) -> dict:
    """The ``stages.json`` of an export, its entries checked for shape (not yet their files)."""
    src = Path(src)
    if not src.exists():
        raise ExportError(f"{src} does not exist")
    path = src / INDEX_FILE
    if not path.is_file():
        raise ExportError(
            f"{src} is not an export of finished stages (no {INDEX_FILE}; "
            "make one with lhf reproduce ... --export-stages DIR)"
        )
    try:
        index = read_json(path)
        if not isinstance(index, dict):
            raise UserError("not a JSON object")
        if index.get("format") != FORMAT:
            raise UserError(f"format {index.get('format')!r}, this version reads {FORMAT}")
        entries = index.get("stages")
        if not isinstance(entries, list):
            raise UserError("'stages' is not a list")
        for i, e in enumerate(entries):
            _check_entry(e, i)
    except ValueError as exc:
        raise ExportError(f"{path} is unreadable: {exc}") from exc
    return index


def _check_entry(e, i: int) -> None:
    if not isinstance(e, dict) or not {"kind", "label", "hash", "path"} <= set(e):
        raise UserError(f"stage {i} is not {{kind, label, hash, path}}")
    if e["kind"] not in KINDS:
        raise UserError(f"stage {i} has an unknown kind {e['kind']!r} (one of {KINDS})")
    if not isinstance(e["hash"], str) or not _HASH.fullmatch(e["hash"]):
        raise UserError(f"stage {i}'s hash is not a SHA-256")
    want = (
        f"{e['kind']}/{e['hash'][:12]}"
        if e["kind"] in PORTABLE
        else f"records/{e['kind']}-{e['hash'][:12]}.json"
    )
    if e["path"] != want:  # also keeps every path inside the export
        raise UserError(f"stage {i}'s path is {e['path']!r}, expected {want!r}")
    if e["kind"] in PORTABLE and not isinstance(e.get("files"), dict):
        raise UserError(f"stage {i} lists no files")


def export_stages(stages: list[Stage], work: str | Path, dest: str | Path, about: dict) -> dict:
    """Copy the finished stages of ``stages`` from ``work`` into ``dest`` (an lhf ``stages``
    folder; an earlier export there is replaced only when this one holds all its evaluations);
    ``about`` (the command) goes into ``stages.json``.  Finished stages whose outputs were not
    here but whose record was (imported) are exported as records again.
    Returns the counts: ``{"portable": n, "records": n, "not_done": n}``."""
    work, dest = Path(work), Path(dest)
    if not work.is_dir():
        raise ExportError(f"the work folder {work} does not exist: nothing to export")
    if dest.resolve().is_relative_to(work.resolve()):
        raise ExportError(f"{dest} is inside the work folder {work}: export somewhere else")
    done = [s for s in stages if s.done(work) or (s.path(work) / RECORD_FILE).exists()]
    if not any(s.kind in PORTABLE and s.done(work) for s in done):
        raise ExportError(
            f"no evaluation of this plan is finished in {work} (another --work, --preset, "
            "--runs or --objectives?): nothing to export"
        )
    keep = {s.hash for s in done if s.kind in PORTABLE}
    if dest.is_dir() and any(dest.iterdir()):
        try:  # an earlier export (someone's folder: output_folder refuses it below)
            old = {e["hash"] for e in read_index(dest)["stages"] if e["kind"] in PORTABLE}
        except ExportError as exc:
            if (dest / INDEX_FILE).exists():
                raise ExportError(
                    f"{dest} holds an export whose index cannot be read ({exc}): it may hold "
                    "evaluations this one would drop; export to another folder"
                ) from None
            old = set()
        lost = old - keep
        if lost:
            raise ExportError(
                f"{dest} holds {len(lost)} evaluation(s) this export would not: export to "
                "another folder (or delete that one yourself)"
            )
    entries = []
    with output_folder(
        dest, "stages", overwrite=True, inputs=[work], own_nested=["evaluation"]
    ) as out:
        for s in done:
            src = s.path(work)
            entry = {"kind": s.kind, "label": s.label, "hash": s.hash}
            if s.kind in PORTABLE:
                target = out / s.kind / src.name
                shutil.copytree(src, target, ignore=shutil.ignore_patterns(LOG_FILE, ".*.lock"))
                entry["path"] = f"{s.kind}/{src.name}"
                entry["files"] = _files(target)
            else:
                name = DONE_FILE if s.done(work) else RECORD_FILE
                record = read_json(src / name)
                entry["path"] = f"records/{s.kind}-{src.name}.json"
                write_json_atomic(record, out / entry["path"])
            entries.append(entry)
        write_json_atomic({"format": FORMAT, **about, "stages": entries}, out / INDEX_FILE)
    portable = sum(e["kind"] in PORTABLE for e in entries)
    not_done = len(stages) - len(entries)
    return {"portable": portable, "records": len(entries) - portable, "not_done": not_done}


def _read_stage(src: Path, e: dict) -> dict:
    """An entry's recorded ``stage.json``, checked: its files' checksums and its config's hash."""
    path = src / e["path"]
    if e["kind"] in PORTABLE:
        if not path.is_dir():
            raise ExportError(f"{src}: stage {e['label']!r} is missing ({e['path']})")
        found = _files(path)
        if found != e["files"]:
            bad = sorted(
                k for k in set(found) | set(e["files"]) if found.get(k) != e["files"].get(k)
            )
            raise ExportError(
                f"{src}: stage {e['label']!r} ({e['path']}) changed since it was exported "
                f"({', '.join(bad[:3])}{', ...' if len(bad) > 3 else ''}): nothing was imported"
            )
        path = path / DONE_FILE
    try:
        done = read_json(path)
        ok = done.get("kind") == e["kind"] and _identity(done) == e["hash"]
    except (OSError, ValueError, AttributeError, KeyError, TypeError) as exc:
        raise ExportError(f"{src}: stage {e['label']!r} is unreadable: {exc}") from exc
    if not ok:
        raise ExportError(
            f"{src}: stage {e['label']!r} ({e['path']}) does not match its recorded config "
            "(edited or damaged): nothing was imported"
        )
    return done


def check_export(src: str | Path) -> list[str]:
    """What is wrong with an export (``lhf verify``): its index, and per stage its files'
    checksums and its config's hash; empty when it imports cleanly."""
    try:
        index = read_index(src)
    except ExportError as exc:
        return [str(exc)]
    problems = []
    for e in index["stages"]:
        try:
            _read_stage(Path(src), e)
        except ExportError as exc:
            problems.append(str(exc).removesuffix(": nothing was imported"))
    return problems


def import_stages(src: str | Path, work: str | Path, plan: list[Stage], dry: bool = False) -> dict:
    """Copy the stages of ``plan`` exported to ``src`` into ``work`` (those not done there);
    ``dry``: only check the export (raises as the import would), copy nothing.

    The whole export is checked before anything is copied (``ExportError`` names what is wrong).
    Returns the counts: ``{"imported": n, "records": n, "present": n, "evaluations_in_plan": n,
    "evaluations": n, "about": stages.json less its list}``."""
    src, work = Path(src), Path(work)
    index = read_index(src)
    if work.resolve().is_relative_to(src.resolve()):
        raise ExportError(f"the work folder {work} is inside the export {src}: use another --work")
    kind, problems = check_manifest(src)
    if kind is not None and problems:  # stages.json or a record edited after the export
        raise ExportError(
            f"{src} changed since it was exported ({problems[0]}): nothing was imported"
        )
    planned = {s.hash for s in plan}
    checked = [(e, _read_stage(src, e)) for e in index["stages"]]
    if dry:
        return {}
    about = {k: v for k, v in index.items() if k != "stages"}
    counts = {"imported": 0, "records": 0, "present": 0, "about": about}
    counts["evaluations"] = sum(e["kind"] in PORTABLE for e, _ in checked)
    counts["evaluations_in_plan"] = sum(
        e["kind"] in PORTABLE and e["hash"] in planned for e, _ in checked
    )
    for e, done in checked:
        if e["hash"] not in planned:
            continue  # another experiment's, preset's or version's: nothing here reads it
        target = work / e["kind"] / e["hash"][:12]
        if done_record(target) is not None:
            counts["present"] += 1
        elif e["kind"] in PORTABLE:
            origin = {
                "from": str(src.resolve()),
                **{k: about.get(k) for k in ("created", "versions")},
            }
            _copy_in(src / e["path"], target, {**done, "imported": origin})
            counts["imported"] += 1
        elif (target / RECORD_FILE).exists():
            counts["present"] += 1
        else:
            target.mkdir(parents=True, exist_ok=True)
            write_json_atomic(done, target / RECORD_FILE)
            counts["records"] += 1
    return counts


def _copy_in(path: Path, target: Path, done: dict) -> None:
    """``path`` becomes ``target`` whole or not at all, its ``stage.json`` = ``done``: a copy
    beside it, then a rename; what an interrupted stage left there is removed after."""
    target.parent.mkdir(parents=True, exist_ok=True)
    for stale in target.parent.glob(f".{target.name}.importing-*"):  # of an interrupted import
        shutil.rmtree(stale, ignore_errors=True)
    tmp = target.parent / f".{target.name}.importing-{os.getpid()}"
    shutil.copytree(path, tmp)
    write_json_atomic(done, tmp / DONE_FILE)
    old = None
    if target.exists():
        old = target.parent / f".{target.name}.replaced-{os.getpid()}"
        os.replace(target, old)
    os.replace(tmp, target)
    if old is not None:
        shutil.rmtree(old)
