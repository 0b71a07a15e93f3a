"""Output folders: what a command may do with the folder it writes (README "Safety").

One policy for every command that writes a folder (collect, derive, filter, materialize, train,
evaluate, compare, reproduce):

- A folder is written only while this process holds its lock (``fcntl.flock`` on ``.NAME.lock``
  beside it, holding the writer's PID, deleted when the writer ends): a second writer gets an
  error naming that PID.
- An empty or missing folder is used as is.  A non-empty one only when it is an artifact of the same
  kind (``.lhf_output.json`` says so; folders written before the marker are recognised by their
  files), and then only with ``resume`` (continue it) or ``overwrite`` (replace it).  Anything else
  (someone's files, an artifact of another kind) is never written into or deleted.
- The folder may not be or contain an input of the same command (replacing it would delete the
  input); a folder inside an input is allowed (``lhf evaluate --model m --out m/eval``), except
  inside an input dataset (it would become part of the dataset).
- On success the marker records every file's SHA-256 (a manifest; hidden files and the ``mutable``
  ones, e.g. a model card that later evaluations update, left out): ``check_manifest`` and
  ``lhf verify`` find what changed since.
- ``overwrite`` replaces only what the command wrote: a finished artifact holding anything its
  manifest does not list (files added later, a nested artifact such as ``--out MODEL/eval``) is
  refused with their names, never deleted (an old evaluation would not describe the new model).
- ``overwrite`` is atomic at the folder level: the old artifact is renamed aside
  (``.NAME.replaced-PID``), the new one is written under the name, and the old one is deleted only
  once the command succeeded; an error or Ctrl-C puts the old one back (if it was deleted
  meanwhile, the run's unfinished artifact stays, said, and the error is the original one).  A
  killed process leaves the old artifact beside the new one (the next writer names it).
- A run that fails after writing into a folder it started empty leaves it marked in progress
  (the marker without a manifest): ``resume`` continues it, ``overwrite`` replaces it.  One that
  fails before writing anything (a training before its first checkpoint) leaves nothing to resume:
  a folder it created is removed, an empty one it was given is empty again (``DISCARDED``).
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import sys
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from lhf_hf import __version__
from lhf_hf.errors import UserError

from .io import read_json, sha256_file, write_json_atomic
from .signals import interrupts_held, interrupts_ignored

MARKER = ".lhf_output.json"
#: (kind, folder) of every artifact this process completed (switched in), in order: an interrupt
#: that lands after a switch is reported with what it did not undo (``lhf_hf.cli.main``).
COMPLETED: list[tuple[str, Path]] = []
#: (kind, folder, removed) of every artifact this process started and gave up before writing into
#: it (an error or an interrupt; ``removed``: the folder was created for it and is gone, else it
#: was given empty and is empty again): nothing to resume, which ``lhf_hf.cli.main`` says.
DISCARDED: list[tuple[str, Path, bool]] = []
#: What an interrupted upload left, one line each (``utils.hub.push_folder``: nothing committed,
#: or a commit without its tag), said with the interrupt like the two lists above.
PUSHES: list[str] = []


class OutputError(UserError, FileExistsError):
    """The output folder may not be written as asked (a user error: one clear line)."""


def _marker_kind(path: Path) -> str | None:
    try:
        return read_json(path / MARKER).get("kind")
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
        if _is_within(target, src) and _marker_kind(src) == "dataset":
            # a dataset folder is read whole (datasets.load_dataset, the data/ globs, the
            # manifest's added-file check): an output inside it would change the dataset
            raise OutputError(
                f"the output folder {out} is inside the input dataset {given}: its files would "
                "become part of the dataset (datasets.load_dataset and lhf verify read the whole "
                "folder); choose an output outside it"
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


def _not_written_by_it(root: Path, own_nested: Iterable[str] = ()) -> list[str]:
    """What a finished artifact holds beyond its manifest: files added since (a user's notes) and
    nested artifacts (``lhf evaluate --out MODEL/eval``) other than those of the ``own_nested``
    kinds, which the command writes itself (a report's comparisons).  An unfinished artifact (no
    manifest) has nothing to compare with: [] (it is replaced whole, as before)."""
    try:
        marker = read_json(root / MARKER)
    except (OSError, ValueError):
        return []
    files = marker.get("files") if isinstance(marker, dict) else None
    if files is None:
        return []
    nested = []
    for folder, dirs, _ in os.walk(root):
        here = Path(folder)
        for d in list(dirs):
            if (here / d / MARKER).exists():
                kind = _marker_kind(here / d) or "output"
                if kind not in own_nested:
                    nested.append(f"{(here / d).relative_to(root)}/ (an lhf {kind})")
                dirs.remove(d)
    added = [
        str(rel) for rel in _listed_files(root, marker.get("mutable", ())) if str(rel) not in files
    ]
    # what the manifest never lists, and so a manifest check cannot see: hidden files and
    # folders (a user's .notes, a .git) and empty folders
    unseen = []
    for folder, dirs, names in os.walk(root):
        here = Path(folder)
        dirs[:] = [d for d in dirs if not (here / d / MARKER).exists()]
        for name in [*dirs, *names]:
            rel = (here / name).relative_to(root)
            if name.startswith(".") and not _ours_hidden(name):
                unseen.append(f"{rel}{'/' if name in dirs else ''}")
            elif name in dirs and not any((here / name).iterdir()):
                unseen.append(f"{rel}/ (empty)")
        dirs[:] = [d for d in dirs if not d.startswith(".")]
    return sorted(nested) + added + sorted(unseen)


def _ours_hidden(name: str) -> bool:
    """Hidden names lhf writes itself: markers, locks, atomic writes' temporaries, asides."""
    return (
        name == MARKER
        or name.endswith((".lock", ".tmp"))
        or any(f".{tag}-" in name for tag in ("replaced", "unfinished", "importing"))
    )


def record_manifest(out: Path, kind: str, mutable: Iterable[str] = ()) -> None:
    """Write the marker with the SHA-256 of every file of ``out`` (hidden and ``mutable`` ones
    left out)."""
    mutable = sorted(mutable)
    files = {str(rel): sha256_file(out / rel) for rel in _listed_files(out, mutable)}
    marker = {"kind": kind, "lhf_hf": __version__, "mutable": mutable, "files": files}
    write_json_atomic(marker, out / MARKER)


def check_manifest(path: str | Path, prefix: str | None = None) -> tuple[str | None, list[str]]:
    """(kind, problems) of a folder against its marker's manifest: files missing, changed or
    added since the command that wrote it ended.  No manifest: (kind or None, [a note]).
    ``prefix``: only the recorded files under it (e.g. ``meta/``), and no added-file check."""
    path = Path(path)
    if not (path / MARKER).is_file():
        return None, [f"{path} has no {MARKER} (written before manifests, or not by lhf_hf)"]
    try:
        marker = read_json(path / MARKER)
    except (OSError, ValueError):
        marker = None
    files = marker.get("files") if isinstance(marker, dict) else None
    if (
        not isinstance(marker, dict)
        or not isinstance(marker.get("kind"), str)
        or not (files is None or isinstance(files, dict))
    ):  # a damaged manifest must not read as "no manifest": nothing in the folder is vouched for
        raise UserError(
            f"{path / MARKER} is damaged (not the manifest an lhf command writes): the folder "
            "cannot be checked; restore the file or run the command that wrote the folder again"
        )
    if files is None:
        return marker.get("kind"), [f"{path}: unfinished (its command has not ended)"]
    problems = []
    if prefix is not None:
        files = {rel: d for rel, d in files.items() if rel.startswith(prefix)}
    for rel, digest in sorted(files.items()):
        f = path / rel
        if not f.is_file():
            problems.append(f"{rel}: missing")
        elif sha256_file(f) != digest:
            problems.append(f"{rel}: changed (SHA-256 differs from the recorded one)")
    for rel in [] if prefix is not None else _listed_files(path, marker.get("mutable", ())):
        if str(rel) not in files:
            problems.append(f"{rel}: added after the folder was written")
    return marker.get("kind"), problems


def changed_since_written(folder: str | Path, names: Iterable[str]) -> list[str]:
    """Which of the files ``names`` in ``folder`` differ from the manifest of the finished
    artifact that holds them (``folder`` itself or the folder above it, e.g. a ``checkpoint-N``
    of a model): what a reader must not trust.  [] where no finished artifact records them."""
    folder = Path(folder).resolve()
    for root in (folder, folder.parent):
        try:
            files = read_json(root / MARKER).get("files")
        except (OSError, ValueError, AttributeError):
            continue
        if files is None:
            return []  # unfinished (e.g. a training still running): nothing recorded yet
        changed = []
        for name in names:
            rel = str((folder / name).relative_to(root))
            f = root / rel
            if rel in files and (not f.is_file() or sha256_file(f) != files[rel]):
                changed.append(rel)
        return changed
    return []


def _acquire(path: Path, wait: bool) -> int:
    """An open descriptor of the lock file ``path`` (created), holding an exclusive ``flock`` on
    the file that is at ``path``; ``wait=False``: ``BlockingIOError`` (with ``.fd``, still open,
    to read the holder from) when another process holds it.

    The holder deletes the file when it lets go (``_release``), so a process that opened the file
    before that may lock a file that is no longer at ``path`` while a third process creates and
    locks a new one: both would hold "the lock".  A lock counts only if the file locked is still
    the one at ``path`` (same device and inode), else it is let go and taken again."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError as exc:
            exc.fd = fd
            raise
        except BaseException:
            os.close(fd)
            raise
        try:
            now = os.stat(path)
        except FileNotFoundError:
            now = None
        held = os.fstat(fd)
        if now is not None and (now.st_dev, now.st_ino) == (held.st_dev, held.st_ino):
            return fd
        os.close(fd)  # its holder deleted it after this process opened it: lock the new one


def _release(path: Path, fd: int) -> None:
    """Delete the lock file while still holding it (no one else can hold the file at ``path``
    now, so it is this process's), then let go: a process waiting on it finds it gone and takes
    the lock on a new file (``_acquire``).  A killed process leaves its file; the next holder
    deletes it."""
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    finally:
        os.close(fd)  # releases the lock


@contextmanager
def _lock(out: Path) -> Iterator[None]:
    lock_path = out.parent / f".{out.name}.lock"
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fd = _acquire(lock_path, wait=False)
    except BlockingIOError as exc:
        try:
            holder = os.pread(exc.fd, 32, 0).decode(errors="replace").strip() or "?"
        finally:
            os.close(exc.fd)
        raise OutputError(
            f"{out} is being written by another process (PID {holder}); wait for it to end "
            "or choose another output"
        ) from None
    except OSError as exc:
        raise OutputError(
            f"cannot write the output folder {out}: {exc.strerror} ({exc.filename})"
        ) from None
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        _release(lock_path, fd)


@contextmanager
def file_lock(path: Path) -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``path`` (created; deleted when let go) for a
    read-modify-write of a shared file, e.g. a model's evaluations list that concurrent
    ``lhf evaluate`` runs append to; waits."""
    fd = _acquire(path, wait=True)
    try:
        yield
    finally:
        _release(path, fd)


def _stale_replacements(out: Path) -> list[Path]:
    return sorted(out.parent.glob(f".{out.name}.replaced-*"))


def _only_in_progress_marker(path: Path) -> bool:
    """The folder holds nothing but a marker without a manifest (a run that wrote nothing)."""
    if [p.name for p in _content(path)] != [MARKER]:
        return False
    try:
        return "files" not in read_json(path / MARKER)
    except (OSError, ValueError, TypeError):
        return False


def _aside(real: Path, tag: str = "replaced") -> Path:
    """A free ``.NAME.TAG-PID`` name (PIDs repeat after a restart: ``-2``, ``-3`` ...)."""
    base = real.parent / f".{real.name}.{tag}-{os.getpid()}"
    aside, n = base, 1
    while aside.exists():
        n += 1
        aside = base.with_name(f"{base.name}-{n}")
    return aside


def _content(path: Path) -> list[Path]:
    """What a folder holds, lock files of nested outputs left out (they are not content)."""
    return [p for p in path.iterdir() if not (p.name.startswith(".") and p.name.endswith(".lock"))]


def preflight(
    out: str | Path,
    kind: str,
    *,
    overwrite: bool = False,
    resume: bool = False,
    inputs: Iterable[str | Path | None] = (),
    legacy: Iterable[str] = (),
    resumable: bool = False,
    own_nested: Iterable[str] = (),
) -> Path:
    """The checks of ``output_folder`` without writing anything: whether ``out`` may be written
    as asked (raises ``OutputError`` if not).  Returns the real path (symlinks resolved)."""
    if resume and overwrite:
        raise UserError("resume and overwrite exclude each other")
    given = Path(out)
    if given.exists() and not given.is_dir():
        raise OutputError(f"{given} is a file, not a folder: choose another output")
    real = given.resolve()  # a symlinked output is its target: one lock, no renamed link
    check_not_an_input(real, inputs)
    if real.is_dir() and _content(real):
        marked = _marker_kind(real)
        if not holds_kind(real, kind, legacy):
            action = "replace" if overwrite else "write into"
            raise OutputError(
                f"{given} holds {describe(real)}, not an lhf {kind}: refusing to {action} it; "
                "choose another output"
            )
        if overwrite and marked is None:
            # files that look like an older lhf artifact may be someone's own: never deleted
            raise OutputError(
                f"{given} has no {MARKER} (written before lhf_hf marked its outputs, or not by "
                f"lhf_hf): refusing to replace it; delete it yourself if it is yours"
            )
        foreign = _not_written_by_it(real, tuple(own_nested)) if overwrite else []
        if foreign:
            shown = ", ".join(foreign[:6]) + (
                f" and {len(foreign) - 6} more" if len(foreign) > 6 else ""
            )
            raise OutputError(
                f"{given} holds {len(foreign)} entr{'y' if len(foreign) == 1 else 'ies'} its "
                f"{kind} did not write ({shown}): --overwrite replaces only what the command "
                "wrote; move them out (or delete them), then overwrite"
            )
        if not overwrite and not resume:
            hint = "--resume to continue it or " if resumable else ""
            state = "an unfinished" if _is_unfinished(real) else "an"
            raise OutputError(
                f"{given} already holds {state} lhf {kind}: pass {hint}--overwrite to replace "
                "it, or choose another output"
            )
    return real


def _stale_note(out: Path, kind: str) -> None:
    for stale in _stale_replacements(out):
        _, problems = check_manifest(stale)
        state = "complete (its manifest checks)" if not problems else "incomplete"
        print(
            f"lhf: note: {stale} is an earlier {kind} of {out}, {state}, set aside by an "
            f"interrupted --overwrite: restore it with `rm -rf {out} && mv {stale} {out}`, or "
            "delete it",
            file=sys.stderr,
        )


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
    own_nested: Iterable[str] = (),
    linked: list | None = None,
    defer_to: list | None = None,
    on_switch: Callable[[], None] | None = None,
) -> Iterator[Path]:
    """Claim ``out`` for writing an artifact of ``kind`` (see the module docstring).

    kind: ``dataset``, ``selection``, ``model``, ``evaluation``, ``comparison``, ``report``.
    overwrite / resume: what may happen to an existing artifact of the same kind (a folder
        without a marker is never replaced; it may be resumed when its ``legacy`` files say so).
    inputs: the command's local inputs (paths; Hub ids and None are skipped).
    legacy: files (glob patterns) that mark an artifact of ``kind`` written before the marker
        existed.
    resumable: the command can continue an interrupted run (named in the error message).
    mutable: files (relative paths) other commands update later: left out of the manifest.
    own_nested: kinds of the artifacts the command itself writes inside ``out`` (a report's
        comparisons): replaced with it; any other nested artifact makes ``overwrite`` refuse.
    linked / defer_to: two artifacts that must change together (a selection and the dataset
        materialised from it): the second, claimed inside the first's block with
        ``defer_to=L``, keeps its set-aside old copy until the first, claimed with ``linked=L``,
        has switched; if the first fails or is interrupted after the second switched, the
        second's old copy is put back too.  (A second with no old copy keeps its new one.)
    on_switch: run within the switch (after the manifest, before the old copy goes, interrupts
        held off), for a record elsewhere that must change with the artifact (an evaluation's
        entry in its model's card); if it fails, the old artifact is put back.
    """
    checks = dict(
        overwrite=overwrite, resume=resume, inputs=inputs, legacy=legacy, own_nested=own_nested
    )
    real = preflight(out, kind, resumable=resumable, **checks)
    with _lock(real):
        preflight(out, kind, resumable=resumable, **checks)  # again, now that we hold the lock
        _stale_note(real, kind)
        replaced = None
        # a folder holding only an in-progress marker (a run killed before it wrote) is reused,
        # not set aside: nothing in it to keep, and repeated kills would pile up empty asides
        unfinished = False
        if overwrite and real.is_dir() and _content(real) and not _only_in_progress_marker(real):
            # an unfinished artifact has no manifest: what in it is the command's is unknown
            unfinished = _is_unfinished(real)
            replaced = _aside(real)
            os.replace(real, replaced)  # atomic: the old artifact is whole until success
        created = not real.exists()
        was_empty = created or not _content(real)
        try:
            real.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            if replaced is not None:
                os.replace(replaced, real)
            raise OutputError(f"cannot create the output folder {out}: {exc.strerror}") from None
        marker = real / MARKER
        before = marker.read_text() if marker.exists() else None
        switched = False
        # in progress: no manifest until the command ends (a resumed folder's old one is dropped)
        write_json_atomic({"kind": kind, "lhf_hf": __version__}, marker)
        try:
            yield real
            # The switch from old to new runs whole: an interrupt landing in it would leave the
            # new artifact without its manifest or the old one half deleted, so it waits and is
            # delivered after (the new artifact is then complete, and said so).  One landing
            # before it (in this very line) still puts the old one back below.
            with interrupts_held():
                record_manifest(real, kind, mutable)
                if on_switch is not None:
                    on_switch()
                if replaced is not None and unfinished:
                    _keep_unfinished(replaced, real, kind)
                elif defer_to is not None:  # the enclosing artifact deletes it when it switches
                    defer_to.append((real, replaced))
                elif replaced is not None:
                    shutil.rmtree(replaced, ignore_errors=True)
                for _, aside in linked or ():
                    if aside is not None:
                        shutil.rmtree(aside, ignore_errors=True)
                COMPLETED.append((kind, real))
            switched = True
        except BaseException as exc:
            if switched:  # an interrupt just after the switch: the new artifact is whole
                raise
            if linked:
                _put_back_linked(linked)
            if replaced is not None and (replaced / MARKER).is_file():  # put it back: nothing lost
                with interrupts_ignored():
                    shutil.rmtree(real, ignore_errors=True)
                    os.replace(replaced, real)
                if isinstance(exc, KeyboardInterrupt | SystemExit):
                    print(f"lhf: {out} holds the earlier {kind} again (unchanged)", file=sys.stderr)
            elif replaced is not None:  # someone deleted it (or part): keep this run's part
                hint = "--resume or --overwrite" if resumable else "--overwrite"
                print(
                    f"lhf: note: {replaced} (the earlier {kind}, set aside) was removed while this "
                    f"run wrote: {out} keeps this run's unfinished {kind} ({hint})",
                    file=sys.stderr,
                )
            elif was_empty and {p.name for p in real.iterdir()} <= {MARKER}:
                # failed before writing: leave nothing (an empty folder given to it stays empty)
                if created:
                    shutil.rmtree(real, ignore_errors=True)
                else:
                    marker.unlink(missing_ok=True)
                DISCARDED.append((kind, real, created))
            elif not was_empty:
                _restore_marker(real, before)
            # else: a folder this run started empty holds part of an lhf artifact: its
            # in-progress marker stays, so that --resume continues it or --overwrite replaces it
            # (without a marker both would refuse it as someone's files)
            raise


def _is_unfinished(path: Path) -> bool:
    try:
        return "files" not in read_json(path / MARKER)
    except (OSError, ValueError, TypeError):
        return False


def _keep_unfinished(aside: Path, real: Path, kind: str) -> None:
    """The unfinished artifact an overwrite replaced is never deleted: without a manifest, files
    someone added to it cannot be told from the command's.  It is kept beside, and named."""
    keep = _aside(real, "unfinished")
    os.replace(aside, keep)
    print(
        f"lhf: note: the unfinished {kind} {real} held is kept at {keep} (an unfinished folder "
        "has no manifest, so files added to it cannot be told apart): delete it once you have "
        "checked it",
        file=sys.stderr,
    )


def _put_back_linked(linked: list) -> None:
    """The enclosing artifact failed after linked ones switched: their old copies come back."""
    with interrupts_ignored():
        for real, aside in linked:
            if aside is not None and (aside / MARKER).is_file():
                shutil.rmtree(real, ignore_errors=True)
                os.replace(aside, real)
                print(f"lhf: {real} holds its earlier version again (unchanged)", file=sys.stderr)
        linked.clear()


def _restore_marker(real: Path, before: str | None) -> None:
    """After a failed run in an existing folder: no marker where there was none (a refused
    --resume leaves someone's folder as it was); the old manifest back when nothing changed."""
    marker = real / MARKER
    if before is None:
        marker.unlink(missing_ok=True)
        return
    try:
        old = json.loads(before)
    except ValueError:
        return
    files = old.get("files")
    if files is not None and all(
        (real / rel).is_file() and sha256_file(real / rel) == digest
        for rel, digest in files.items()
    ):
        write_json_atomic(old, marker)
