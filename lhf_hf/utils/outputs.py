"""Output folders: what a command may do with the folder it writes (README "Safety").

One policy for every command that writes a folder (collect, derive, filter, materialize, train,
evaluate, compare, reproduce):

- A folder is written only while this process holds its lock (``fcntl.flock`` on ``.NAME.lock``
  beside it, holding the writer's PID): a second writer gets an error naming that PID.
- An empty or missing folder is used as is.  A non-empty one only when it is an artifact of the same
  kind (``.lhf_output.json`` says so; folders written before the marker are recognised by their
  files), and then only with ``resume`` (continue it) or ``overwrite`` (replace it).  Anything else
  (someone's files, an artifact of another kind) is never written into or deleted.
- The folder may not be or contain an input of the same command (replacing it would delete the
  input); a folder inside an input is allowed (``lhf evaluate --model m --out m/eval``).
- On success the marker records every file's SHA-256 (a manifest; hidden files and the ``mutable``
  ones, e.g. a model card that later evaluations update, left out): ``check_manifest`` and
  ``lhf verify`` find what changed since.
- ``overwrite`` is atomic at the folder level: the old artifact is renamed aside
  (``.NAME.replaced-PID``), the new one is written under the name, and the old one is deleted only
  once the command succeeded; an error or Ctrl-C puts the old one back.  A killed process leaves
  the old artifact beside the new one (the next writer names it).
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from lhf_hf import __version__

from .io import sha256_file, write_json_atomic

MARKER = ".lhf_output.json"


class OutputError(FileExistsError):
    """The output folder may not be written as asked (a user error: one clear line)."""


def _marker_kind(path: Path) -> str | None:
    try:
        return json.loads((path / MARKER).read_text()).get("kind")
    except (OSError, ValueError, AttributeError):
        return None


def describe(path: Path) -> str:
    """What a folder holds, in words, for error messages."""
    kind = _marker_kind(path)
    if kind:
        return f"an lhf {kind}"
    names = sorted(p.name for p in path.iterdir())
    shown = ", ".join(names[:4]) + (", ..." if len(names) > 4 else "")
    return f"{len(names)} entr{'y' if len(names) == 1 else 'ies'} ({shown})"


def holds_kind(path: Path, kind: str, legacy: Iterable[str] = ()) -> bool:
    """Whether ``path`` is an artifact of ``kind``: its marker says so, or (no marker: written
    before markers existed) one of the ``legacy`` files of that kind is there."""
    marked = _marker_kind(path)
    if marked is not None:
        return marked == kind
    return any(next(path.glob(pattern), None) is not None for pattern in legacy)


def _is_within(inner: Path, outer: Path) -> bool:
    return inner == outer or outer in inner.parents


def check_not_an_input(out: Path, inputs: Iterable[str | Path | None]) -> None:
    """Refuse an output folder that is or contains an existing local input."""
    target = out.resolve()
    for given in inputs:
        if given is None or not Path(given).exists():
            continue  # a Hub repo id, or nothing: no local folder to protect
        src = Path(given).resolve()
        if _is_within(src, target):
            relation = "is" if src == target else "contains"
            raise OutputError(
                f"the output folder {out} {relation} the input {given}: choose another output"
            )


def _listed_files(root: Path, mutable: Iterable[str]) -> list[Path]:
    """Files a manifest covers: not hidden, not ``mutable``, and not inside a nested artifact
    (a subfolder with its own marker, e.g. ``lhf evaluate --out MODEL/eval``)."""
    skip = set(mutable)
    out = []
    for folder, dirs, files in os.walk(root):
        here = Path(folder)
        dirs[:] = [d for d in dirs if not d.startswith(".") and not (here / d / MARKER).exists()]
        for name in files:
            rel = (here / name).relative_to(root)
            if not name.startswith(".") and str(rel) not in skip:
                out.append(rel)
    return sorted(out)


def record_manifest(out: Path, kind: str, mutable: Iterable[str] = ()) -> None:
    """Write the marker with the SHA-256 of every file of ``out`` (hidden and ``mutable`` ones
    left out)."""
    mutable = sorted(mutable)
    files = {str(rel): sha256_file(out / rel) for rel in _listed_files(out, mutable)}
    marker = {"kind": kind, "lhf_hf": __version__, "mutable": mutable, "files": files}
    write_json_atomic(marker, out / MARKER)


def check_manifest(path: str | Path) -> tuple[str | None, list[str]]:
    """(kind, problems) of a folder against its marker's manifest: files missing, changed or
    added since the command that wrote it ended.  No manifest: (kind or None, [a note])."""
    path = Path(path)
    try:
        marker = json.loads((path / MARKER).read_text())
    except (OSError, ValueError):
        return None, [f"{path} has no {MARKER} (written before manifests, or not by lhf_hf)"]
    files = marker.get("files")
    if files is None:
        return marker.get("kind"), [f"{path}: unfinished (its command has not ended)"]
    problems = []
    for rel, digest in sorted(files.items()):
        f = path / rel
        if not f.is_file():
            problems.append(f"{rel}: missing")
        elif sha256_file(f) != digest:
            problems.append(f"{rel}: changed (SHA-256 differs from the recorded one)")
    for rel in _listed_files(path, marker.get("mutable", ())):
        if str(rel) not in files:
            problems.append(f"{rel}: added after the folder was written")
    return marker.get("kind"), problems


@contextmanager
def _lock(out: Path) -> Iterator[None]:
    lock_path = out.parent / f".{out.name}.lock"
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as exc:
        raise OutputError(
            f"cannot write the output folder {out}: {exc.strerror} ({exc.filename})"
        ) from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            raise OutputError(
                f"{out} is being written by another process (PID {holder}); wait for it to end "
                "or choose another output"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


def _stale_replacements(out: Path) -> list[Path]:
    return sorted(out.parent.glob(f".{out.name}.replaced-*"))


@contextmanager
def output_folder(
    out: str | Path,
    kind: str,
    *,
    overwrite: bool = False,
    resume: bool = False,
    inputs: Iterable[str | Path | None] = (),
    legacy: Iterable[str] = (),
    resumable: bool = False,
    mutable: Iterable[str] = (),
) -> Iterator[Path]:
    """Claim ``out`` for writing an artifact of ``kind`` (see the module docstring).

    kind: ``dataset``, ``selection``, ``model``, ``evaluation``, ``comparison``, ``report``.
    overwrite / resume: what may happen to an existing artifact of the same kind.
    inputs: the command's local inputs (paths; Hub ids and None are skipped).
    legacy: files (glob patterns) that mark an artifact of ``kind`` written before the marker
        existed.
    resumable: the command can continue an interrupted run (named in the error message).
    mutable: files (relative paths) other commands update later: left out of the manifest.
    """
    out = Path(out)
    if resume and overwrite:
        raise ValueError("resume and overwrite exclude each other")
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out} is a file, not a folder: choose another output")
    check_not_an_input(out, inputs)
    with _lock(out):
        for stale in _stale_replacements(out):
            print(
                f"lhf: note: {stale} is an earlier {kind} of {out} left by an interrupted "
                "--overwrite (delete it once the new one is good)",
                file=sys.stderr,
            )
        replaced = None
        if out.is_dir() and any(out.iterdir()):
            if not holds_kind(out, kind, legacy):
                action = "replace" if overwrite else "write into"
                raise OutputError(
                    f"{out} holds {describe(out)}, not an lhf {kind}: refusing to {action} it; "
                    "choose another output"
                )
            if overwrite:
                replaced = out.parent / f".{out.name}.replaced-{os.getpid()}"
                os.replace(out, replaced)  # atomic: the old artifact is whole until success
            elif not resume:
                hint = "--resume to continue it or " if resumable else ""
                raise OutputError(
                    f"{out} already holds an lhf {kind}: pass {hint}--overwrite to replace it, "
                    "or choose another output"
                )
        created = not out.exists()
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            if replaced is not None:
                os.replace(replaced, out)
            raise OutputError(f"cannot create the output folder {out}: {exc.strerror}") from None
        # in progress: no manifest until the command ends (a resumed folder's old one is dropped)
        write_json_atomic({"kind": kind, "lhf_hf": __version__}, out / MARKER)
        try:
            yield out
        except BaseException:
            if replaced is not None:  # put the old artifact back: nothing lost
                shutil.rmtree(out, ignore_errors=True)
                os.replace(replaced, out)
            elif created and {p.name for p in out.iterdir()} <= {MARKER}:
                shutil.rmtree(out, ignore_errors=True)  # failed before writing: leave nothing
            raise
        record_manifest(out, kind, mutable)
        if replaced is not None:
            shutil.rmtree(replaced, ignore_errors=True)
