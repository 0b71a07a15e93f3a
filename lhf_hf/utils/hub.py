"""Hub access (docs/design.md 4 and 8), knowing no artifact kind: repo ids, ``resolve`` (repo id -> local
folder), provenance, and ``push_folder`` (a folder as ONE commit, plus an optional tag).

``push_folder`` uploads a folder as one commit (the Hub applies a commit all-or-nothing, so a failed
push leaves the repo as it was), with the card it is given, removes files the folder no longer has,
and can move a git tag onto the new commit (LeRobot loaders resolve a dataset's codebase version
through the tag ``v3.0``).  Each artifact (histories, selection, checkpoint) owns its card and its
checks; ``lhf_hf.hub.push`` finds the artifact a folder holds and calls this.

Reading goes through ``resolve``: a spec that is an existing local path is used as is; otherwise
``ORG/NAME`` or ``ORG/NAME@REVISION`` is fetched with ``snapshot_download`` and parsed locally, so
every reader (``load_histories``, ``load_selection``, ``load_model``) accepts both.  The endpoint,
token and cache come from the usual ``HF_ENDPOINT`` / ``HF_TOKEN`` / ``HF_HOME`` variables.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path

from huggingface_hub import (
    CommitOperationAdd,
    CommitOperationDelete,
    HfApi,
    constants,
    get_token,
    snapshot_download,
)
from huggingface_hub.errors import (
    GatedRepoError,
    HfHubHTTPError,
    HFValidationError,
    LocalEntryNotFoundError,
    RepositoryNotFoundError,
    RevisionNotFoundError,
)
from huggingface_hub.utils import validate_repo_id as _validate

from lhf_hf import constants as C
from lhf_hf.errors import NotFoundError, UserRuntimeError

from .io import read_json, sha256_file
from .outputs import MARKER, PUSHES, check_manifest

#: Never uploaded: Trainer's intermediate checkpoints (optimizer state), hidden and private files,
#: half-written temporaries and the pickled TrainingArguments.
_EXCLUDED_DIRS = re.compile(r"^(checkpoint-\d+|\..*|_.*|__pycache__)$")
_EXCLUDED_FILES = re.compile(r"^(\..*|_.*|.*\.tmp|training_args\.bin)$")
_REPO_REF = re.compile(r"^(?P<repo>[A-Za-z0-9][\w.\-]*/[\w.\-]+)(?:@(?P<rev>[^\s@]+))?$")


class HubError(UserRuntimeError):
    """A Hub operation failed; the message says what and how to fix it."""


@dataclass(frozen=True)
class HubRef:
    """``ORG/NAME`` (and an optional revision: a branch, tag or commit)."""

    repo_id: str
    revision: str | None = None

    def __str__(self) -> str:
        return self.repo_id + (f"@{self.revision}" if self.revision else "")


def parse_hub_ref(spec: str) -> HubRef | None:
    """``"org/name"`` / ``"org/name@rev"`` -> ``HubRef``; ``None`` when ``spec`` is not of that shape
    (a relative path such as ``data/x`` has the shape too: callers try the local path first)."""
    m = _REPO_REF.match(str(spec))
    if m is None or str(spec).startswith(("./", "../", "/", "~")):
        return None
    return HubRef(m["repo"], m["rev"])


def validate_repo_id(repo_id: str) -> str:
    if parse_hub_ref(repo_id) is None or "@" in repo_id:
        raise HubError(f"invalid repo id {repo_id!r}: expected ORG/NAME (letters, digits, - _ .)")
    try:
        _validate(repo_id)
    except HFValidationError as exc:
        raise HubError(f"invalid repo id {repo_id!r}: {exc}") from None
    return repo_id


def endpoint() -> str:
    return constants.ENDPOINT


# ---------------------------------------------------------------------------- read
def is_hub_snapshot(path: Path) -> bool:
    """True for a folder inside the huggingface_hub cache (read-only: never write into it)."""
    return path.parent.name == "snapshots" and path.parent.parent.name.count("--") >= 2


def resolve(spec: str | Path, repo_type: str, what: str = "artifact") -> Path:
    """A local folder for ``spec``: the path itself when it exists, else a snapshot of the repo.

    The ``datasets`` convention: a local folder wins, else ``ORG/NAME[@REV]`` is a repo id.  A path
    with ``./``, ``../``, a leading ``/`` or ``~``, or more than one ``/`` is only ever local.
    """
    p = Path(spec).expanduser()
    if p.exists():
        return p
    ref = parse_hub_ref(str(spec))
    if ref is None:
        raise NotFoundError(
            f"no {what} at {str(spec)!r}: no such local folder (and not of the Hub repo id form "
            "ORG/NAME[@REVISION])"
        )
    try:
        path = download(ref, repo_type)
    except HubError as exc:
        why = str(exc).splitlines()[0]
        raise HubError(
            f"no {what} at {str(spec)!r}: no local folder of that name, and no Hub {repo_type} "
            f"repo {ref} ({why})"
        ) from None
    check_snapshot(path, ref)
    return path


def download(ref: HubRef, repo_type: str, files: list[str] | None = None) -> Path:
    """``snapshot_download`` (of ``files`` only, if given) with errors that say what is wrong.
    The folder returned is named by the commit it holds."""
    where = f"{repo_type} repo {ref} on {endpoint()}"
    try:
        return Path(
            snapshot_download(
                ref.repo_id, repo_type=repo_type, revision=ref.revision, allow_patterns=files
            )
        )
    except HFValidationError as exc:
        raise HubError(f"invalid repo id {str(ref)!r}: {exc}") from None
    except RevisionNotFoundError:
        raise HubError(f"{where}: revision {ref.revision!r} does not exist") from None
    except GatedRepoError:
        raise HubError(f"{where} is gated: request access on the Hub, then log in") from None
    except RepositoryNotFoundError:
        # some Hub servers (mirrors) answer a missing revision as a missing repo: asked again
        # without the revision, a repo that exists says which it was
        refs = _refs(ref.repo_id, repo_type) if ref.revision is not None else None
        if refs is not None:
            raise HubError(
                f"{where}: revision {ref.revision!r} does not exist (it has {', '.join(refs)})"
            ) from None
        raise HubError(
            f"{where} does not exist (or is private: log in with `hf auth login` or set HF_TOKEN)"
        ) from None
    except LocalEntryNotFoundError as exc:
        raise HubError(
            f"{where}: cannot reach the Hub and it is not in the cache ({exc})"
        ) from None
    except HfHubHTTPError as exc:
        raise HubError(f"{where}: {exc}") from None


def _refs(repo_id: str, repo_type: str) -> list[str] | None:
    """The branches and tags of a repo, or None where it cannot be listed (absent, private, the
    Hub unreachable now: the first error then stands as it was)."""
    try:
        refs = HfApi().list_repo_refs(repo_id, repo_type=repo_type)
    except Exception:  # noqa: BLE001
        return None
    return [r.name for r in (*refs.branches, *refs.tags)]


def error_text(exc: BaseException) -> str:
    """An exception and its cause in one text, the cause only where it adds words (the Hub's
    HTTP errors repeat their cause's message, a failed connection its socket error)."""
    text = str(exc).strip()
    cause = str(exc.__cause__).strip() if exc.__cause__ is not None else ""
    if cause and cause not in text:
        text = f"{text}; {cause}"
    unauthorized = "401" in text.split("\n", 1)[0]
    # one line: httpx's pointer to the status code's documentation says nothing the code does not
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    text = " ".join(line for line in lines if not line.startswith("For more information check"))
    if unauthorized:
        text += " (log in with `hf auth login`, set HF_TOKEN, or pass --token)"
    return text


def source_of(spec: str | Path, path: Path) -> str:
    """What to record as an artifact's origin: ``org/name@commit`` for a Hub snapshot, else the
    absolute local path."""
    path = Path(path)
    if is_hub_snapshot(path) and not Path(spec).expanduser().exists():
        ref = parse_hub_ref(str(spec))
        if ref is not None:
            return f"{ref.repo_id}@{path.name}"
    return str(path.resolve())


def public_source(source: str, what: str = "dataset") -> str:
    """A recorded source as a card may show it: a Hub snapshot (``org/name@commit``) as it is, a
    local folder (recorded absolute by ``source_of``) by its name only: a card is pushed, and the
    machine's paths are not the reader's."""
    if str(source).startswith("/"):
        return f"a local {what} `{Path(source).name}`"
    return f"`{source}`"


# ---------------------------------------------------------------------------- push
def upload_files(root: Path) -> list[str]:
    """Relative paths (posix) of the files ``push`` uploads from ``root``, sorted.

    Regular files inside the folder only: a symbolic link (to a file or a folder) is refused, never
    followed, so a push cannot upload what lies outside the artifact (a link to ``~/.ssh``).
    """
    out = []
    for folder, dirs, files in os.walk(root, followlinks=False):
        here = Path(folder)
        rel_dir = here.relative_to(root)
        if any(_EXCLUDED_DIRS.match(part) for part in rel_dir.parts) or (
            rel_dir.parts and (here / MARKER).exists()
        ):  # another artifact inside this one (an evaluation --out MODEL/eval): not this push's
            dirs[:] = []
            continue
        for name in [*dirs, *files]:
            if (here / name).is_symlink() and not (
                _EXCLUDED_DIRS.match(name) if name in dirs else _EXCLUDED_FILES.match(name)
            ):
                raise HubError(
                    f"{here / name} is a symbolic link (to {os.readlink(here / name)}): push "
                    "uploads the artifact's own files only; replace it with the file itself"
                )
        for name in files:
            if not _EXCLUDED_FILES.match(name):
                out.append((rel_dir / name).as_posix())
    return sorted(out)


def _without_local_paths(value):
    """``value`` (parsed JSON) with every absolute path string replaced by ``local:NAME``."""
    if isinstance(value, dict):
        return {k: _without_local_paths(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_without_local_paths(v) for v in value]
    if isinstance(value, str) and value.startswith("/") and "\n" not in value:
        return f"local:{Path(value).name}"
    return value


def public_contents(root: Path, files: list[str]) -> dict[str, bytes]:
    """What ``push`` uploads in place of some files: the JSON records (a selection's source, a
    derived dataset's, a model's data) with this machine's absolute paths reduced to ``local:NAME``
    (a pushed artifact names no path of the machine that made it; provenance keeps the
    fingerprints).  Files that hold no such path are uploaded as they are (not listed)."""
    out = {}
    for f in files:
        if not f.endswith(".json") or f == MARKER:
            continue
        raw = (root / f).read_bytes()
        if b'"/' not in raw:
            continue
        try:
            data = json.loads(raw)
        except ValueError:
            continue  # not ours to rewrite: uploaded as it is
        public = _without_local_paths(data)
        if public != data:
            out[f] = (json.dumps(public, indent=2) + "\n").encode()
    return out


def pushed_manifest(
    root: Path, files: list[str], replaced: dict[str, bytes] | None = None
) -> bytes | None:
    """The output marker a push uploads beside the files (``utils.outputs``): the folder's kind,
    and the SHA-256 of each uploaded file (of its ``replaced`` contents where given), the card
    left out (the push renders its own).  A load from the Hub checks the downloaded snapshot
    against it (``resolve``).  None: no marker."""
    replaced = replaced or {}
    try:
        marker = read_json(root / MARKER)
    except (OSError, ValueError):
        return None
    pushed = {
        "kind": marker.get("kind"),
        "lhf_hf": marker.get("lhf_hf"),
        "mutable": sorted({*marker.get("mutable", ()), C.CARD_PATH}),
        "files": {
            f: hashlib.sha256(replaced[f]).hexdigest() if f in replaced else sha256_file(root / f)
            for f in files
            if f != C.CARD_PATH
        },
    }
    return json.dumps(pushed, indent=2, sort_keys=True).encode()


def check_pushable(root: Path) -> None:
    """Refuse a folder whose command has not finished, or whose files changed since it did (its
    manifest, ``utils.outputs``): the Hub copy would pass every later check while describing
    something else."""
    kind, problems = check_manifest(root)
    if kind is None:
        raise HubError(
            f"{root} has no {MARKER}: it was not written by an lhf command (or is older than "
            "manifests), so what it holds cannot be verified; not pushed"
        )
    if problems:
        shown = "; ".join(problems[:5]) + (
            f"; and {len(problems) - 5} more" if len(problems) > 5 else ""
        )
        raise HubError(f"{root} is not the {kind} its command wrote ({shown}): not pushed")


def check_snapshot(path: Path, ref: HubRef) -> None:
    """A downloaded snapshot against the manifest its push uploaded (none: nothing to check)."""
    if not (path / MARKER).is_file():
        return
    _, problems = check_manifest(path)
    if problems:
        shown = "; ".join(problems[:5]) + (
            f"; and {len(problems) - 5} more" if len(problems) > 5 else ""
        )
        raise HubError(
            f"{ref}: the files on the Hub are not those `lhf push` uploaded ({shown}); not loaded"
        )


def require_token(token: str | None = None) -> None:
    """Refuse, before any request, a push to the real Hub without a token."""
    if (
        token is None
        and get_token() is None
        and constants.ENDPOINT.rstrip("/")
        in (
            "https://huggingface.co",
            "https://hf.co",
        )
    ):
        raise HubError(
            "pushing to https://huggingface.co needs a write token: run `hf auth login`, set "
            "HF_TOKEN, or pass --token"
        )


def push_folder(
    path: Path,
    repo_id: str,
    *,
    repo_type: str,
    card: str,
    what: str,
    tag: str | None = None,
    private: bool = False,
    revision: str | None = None,
    token: str | None = None,
    commit_message: str | None = None,
    added: dict[str, bytes] | None = None,
) -> dict:
    """Upload ``path`` to ``repo_id`` (created if absent) as one commit, ``card`` as its README.md.

    ``repo_id`` must be valid (``validate_repo_id``); ``what`` names the artifact in messages; ``tag`` (if any) is moved onto the new commit.
    ``added``: relative path -> content the artifact publishes beside (or instead of) the folder's
    files (``HubArtifact.published``).  Returns
    ``{repo_id, repo_type, revision, commit, url, uploaded, deleted, tag}``; raises ``HubError`` on
    any failure (a success is only reported once the commit and the tag exist).
    """
    require_token(token)
    branch = revision or "main"
    added = {f: b for f, b in (added or {}).items() if f != C.CARD_PATH}
    files = sorted(set(upload_files(path)) | set(added))
    public = public_contents(path, [f for f in files if f not in added]) | added
    ops = [
        CommitOperationAdd(f, public[f] if f in public else str(path / f))
        for f in files
        if f != C.CARD_PATH
    ]
    ops.append(CommitOperationAdd(C.CARD_PATH, card.encode()))
    manifest = pushed_manifest(path, files, public)
    if manifest is not None:
        ops.append(CommitOperationAdd(MARKER, manifest))
    api = HfApi(token=token)
    step = "create the repo"
    try:
        api.create_repo(repo_id, repo_type=repo_type, private=private, exist_ok=True)
        if branch != "main":
            step = f"create the branch {branch!r}"
            api.create_branch(repo_id, branch=branch, repo_type=repo_type, exist_ok=True)
        step = "list the files already there"
        remote = set(api.list_repo_files(repo_id, repo_type=repo_type, revision=branch))
        keep = {op.path_in_repo for op in ops} | {".gitattributes"}
        ops += [CommitOperationDelete(f) for f in sorted(remote - keep)]
        step = "commit"
        info = api.create_commit(
            repo_id,
            ops,
            commit_message=commit_message or f"lhf push: {what} from {path.name}",
            repo_type=repo_type,
            revision=branch,
        )
    except Exception as exc:  # noqa: BLE001 (httpx's ConnectError etc.: every failure is one line)
        # Before the commit call returns, the repo is unchanged: the Hub applies a commit whole.
        cause = error_text(exc)
        raise HubError(
            f"push of {path} to {repo_type} repo {repo_id} on {endpoint()} failed at '{step}' "
            f"(nothing was committed): {cause}"
        ) from None
    except BaseException:  # an interrupt: said with it (lhf_hf.cli.main)
        PUSHES.append(
            f"interrupted at '{step}': the Hub applies a commit whole, so {repo_id} holds its "
            "previous files or all of this push's; run `lhf push` again to be sure"
            if step == "commit"  # the request may have reached the server
            else f"interrupted at '{step}': nothing was committed to {repo_id}"
        )
        raise
    if tag is not None:
        try:
            refs = api.list_repo_refs(repo_id, repo_type=repo_type)
            if any(t.name == tag for t in refs.tags):
                api.delete_tag(repo_id, tag=tag, repo_type=repo_type)
            api.create_tag(repo_id, tag=tag, revision=info.oid, repo_type=repo_type)
        except HfHubHTTPError as exc:
            raise HubError(
                f"{path} was committed to {repo_id} ({info.oid[:12]}) but the {tag} tag could not be "
                f"set, so LeRobot loaders will not find it: {exc}.  Run `lhf push` again."
            ) from None
        except BaseException:
            PUSHES.append(
                f"{path} was committed to {repo_id} ({info.oid[:12]}) before the {tag} tag was set: "
                "run `lhf push` again"
            )
            raise
    return {
        "repo_id": repo_id,
        "repo_type": repo_type,
        "revision": branch,
        "commit": info.oid,
        "url": str(info.commit_url),
        "uploaded": len(files) + (C.CARD_PATH not in files) + (manifest is not None),
        "deleted": len(ops) - len(files) - (C.CARD_PATH not in files) - (manifest is not None),
        "tag": tag,
    }


class HubArtifact(ABC):
    """An artifact kind that travels by repo id (in the spirit of ``huggingface_hub.ModelHubMixin``).

    Each kind subclasses this beside its format (``histories``, ``filtering``, ``training``) and says
    how to recognise its folder, how to open it the way its readers will (a broken folder is never
    pushed) and what card it carries; ``lhf_hf.hub.push`` only finds the kind and calls ``push``.
    """

    kind: str = ""
    repo_type: str = ""
    tag: str | None = None  # moved onto each pushed commit

    @classmethod
    @abstractmethod
    def detect(cls, path: Path) -> bool:
        """True when ``path`` holds this kind (its marker files)."""

    @classmethod
    @abstractmethod
    def check(cls, path: Path) -> None:
        """Open ``path`` the way its readers will; raise when it is broken or unfinished."""

    @classmethod
    def verify(cls, path: Path) -> list[str]:
        """Problems found by the deepest check of the kind (``lhf verify``); [] when sound."""
        try:
            cls.check(path)
        except (ValueError, OSError, KeyError) as exc:
            return [str(exc)]
        return []

    @classmethod
    @abstractmethod
    def card(cls, path: Path, repo_id: str, source: str | None = None) -> str:
        """The README.md the pushed artifact carries, with load snippets naming ``repo_id``;
        ``source``: the pinned Hub repo of the artifact's source (``pin_source``), if given."""

    @classmethod
    def published(cls, path: Path, source: str | None = None) -> dict[str, bytes]:
        """Files the push uploads beside the folder's, or instead of them (relative path ->
        content); {}: the folder's files (as ``public_contents`` makes them)."""
        return {}

    @classmethod
    def pin_source(cls, path: Path, source_repo: str) -> str:
        """``ORG/NAME@COMMIT`` of ``source_repo`` once it is checked to hold the data ``path`` was
        made from; the kinds that record a source override this."""
        raise HubError(
            f"{path} is a {cls.kind}: only a selection names the Hub repo of its source dataset "
            "(--source-repo)"
        )

    @classmethod
    def push(
        cls, path: str | Path, repo_id: str, *, source_repo: str | None = None, **kwargs
    ) -> dict:
        """Check, render the card, push as one commit: ``{kind, **push_folder's result}``.
        ``source_repo``: where the artifact's local source was pushed, named in the card and the
        pushed records once checked (``pin_source``)."""
        path = Path(path)
        validate_repo_id(repo_id)
        check_pushable(path)  # finished, and unchanged since its command wrote it
        problems = cls.verify(path)  # and sound by its kind's deepest check (what readers check)
        if problems:
            raise HubError(
                f"{path} fails its {cls.kind} checks ({'; '.join(problems[:5])}): not pushed"
            )
        source = None if source_repo is None else cls.pin_source(path, source_repo)
        out = push_folder(
            path,
            repo_id,
            repo_type=cls.repo_type,
            card=cls.card(path, repo_id, source),
            what=cls.kind,
            tag=cls.tag,
            added=cls.published(path, source),
            **kwargs,
        )
        return {"kind": cls.kind, **out}
