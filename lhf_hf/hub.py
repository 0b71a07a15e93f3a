"""Hub round trips (docs/design.md 4 and 8): push any lhf artifact by repo id; load them back by repo id.

Three artifacts travel, each owning its card and checks beside its format: a learning-history dataset
(``histories.artifact``, also a materialised LHF dataset), an LHF selection (``filtering.artifact``)
and a model checkpoint (``training.artifact``).  ``push`` finds which one a folder holds and lets it
push itself; the Hub access underneath (repo ids, ``resolve``, one-commit uploads) is
``lhf_hf.utils.hub``, which every reader uses and which knows no artifact kind.  This module is the
top layer's entry point (``lhf push``) and re-exports that access API for users.
"""

from __future__ import annotations

from pathlib import Path

from lhf_hf.errors import NotFoundError, UserError
from lhf_hf.filtering.artifact import SelectionArtifact
from lhf_hf.histories.artifact import HistoriesArtifact
from lhf_hf.training.artifact import CheckpointArtifact
from lhf_hf.utils.hub import (
    HubArtifact,
    HubError,
    HubRef,
    download,
    endpoint,
    is_hub_snapshot,
    parse_hub_ref,
    resolve,
    source_of,
    upload_files,
    validate_repo_id,
)

#: Every artifact kind, in the order their folders are recognised.
ARTIFACTS: tuple[type[HubArtifact], ...] = (
    HistoriesArtifact,
    CheckpointArtifact,
    SelectionArtifact,
)
#: artifact kind -> Hub repo type
REPO_TYPES = {a.kind: a.repo_type for a in ARTIFACTS}

__all__ = [
    "ARTIFACTS",
    "REPO_TYPES",
    "HubArtifact",
    "HubError",
    "HubRef",
    "artifact_for",
    "artifact_kind",
    "download",
    "endpoint",
    "is_hub_snapshot",
    "parse_hub_ref",
    "push",
    "resolve",
    "source_of",
    "upload_files",
    "validate_repo_id",
]


def artifact_for(path: Path) -> type[HubArtifact]:
    """The artifact kind whose marker files ``path`` holds."""
    for artifact in ARTIFACTS:
        if artifact.detect(path):
            return artifact
    raise UserError(
        f"{path} is not an lhf artifact: expected a history dataset (meta/info.json), a selection "
        "(filter_config.json) or a checkpoint (config.json)"
    )


def artifact_kind(path: Path) -> str:
    """``histories`` / ``selection`` / ``checkpoint`` by the folder's marker files."""
    return artifact_for(Path(path)).kind


def push(
    path: str | Path,
    repo_id: str,
    *,
    private: bool = False,
    revision: str | None = None,
    token: str | None = None,
    commit_message: str | None = None,
    source_repo: str | None = None,
) -> dict:
    """Push the artifact folder ``path`` to ``repo_id`` (created if absent) as one commit.
    ``source_repo``: for a selection, the Hub repo its local source dataset was pushed to
    (checked, then named in the card and the pushed record).

    Returns ``{kind, repo_id, repo_type, revision, commit, url, uploaded, deleted, tag}``; raises
    ``HubError`` on any failure (a success is only reported once the commit and, for datasets, the
    tag exist).
    """
    path = Path(path)
    if not path.is_dir():
        raise NotFoundError(f"no artifact folder at {path}")
    return artifact_for(path).push(
        path,
        repo_id,
        private=private,
        revision=revision,
        token=token,
        commit_message=commit_message,
        source_repo=source_repo,
    )
