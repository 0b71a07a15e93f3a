"""``verify(path)``: is an lhf output folder what its command wrote, and does it still hold together?

Two checks: the manifest (every file's SHA-256, recorded in ``.lhf_output.json`` when the command
that wrote the folder ended: missing, changed and added files) and the kind's own deepest check
(a dataset: every data file hashed against its fingerprint and every task's returns recomputed from
its rewards; a selection: its source dataset unchanged; a checkpoint: it loads and its dataset is
unchanged; exported stages: each evaluation's files against the export's checksums).  Folders
written before manifests get the second check only, and a note.
"""

from __future__ import annotations

from pathlib import Path

from lhf_hf.errors import NotFoundError, UserError
from lhf_hf.evaluation.compare import read_results
from lhf_hf.evaluation.evaluate import RESULTS_FILE as EVAL_RESULTS
from lhf_hf.filtering.artifact import SelectionArtifact
from lhf_hf.histories.artifact import HistoriesArtifact
from lhf_hf.hub import artifact_for
from lhf_hf.reproduce.portable import check_export
from lhf_hf.training.artifact import CheckpointArtifact
from lhf_hf.utils.hub import HubArtifact, HubError, parse_hub_ref, resolve
from lhf_hf.utils.outputs import MARKER, check_manifest

#: output-folder kind (``utils.outputs``) -> the artifact that checks it (the others: manifest only)
CHECKS: dict[str, type[HubArtifact]] = {
    "dataset": HistoriesArtifact,
    "selection": SelectionArtifact,
    "model": CheckpointArtifact,
}
#: kinds checked by a function of the folder (-> problems) rather than an artifact
FOLDER_CHECKS = {"stages": check_export}  # exported stages: each evaluation's files and config


def verify(path: str | Path) -> dict:
    """``{path, kind, manifest, problems}``: ``problems`` is empty when the folder is sound.

    ``path`` may be a Hub repo id ``ORG/NAME[@REV]`` (a dataset repo, else a model repo): its
    snapshot is checked against the manifest its push uploaded, then by its kind's own check."""
    spec, path = str(path), Path(path)
    if not path.is_dir() and parse_hub_ref(spec) is not None:
        path = _snapshot(spec)
    if not path.is_dir():
        raise NotFoundError(f"no folder at {path}")
    kind, problems = check_manifest(path)
    manifest = kind is not None
    notes = [] if manifest else problems  # an older folder: no manifest to check, only a note
    problems = problems if manifest else []
    artifact = CHECKS.get(kind) if kind else None
    if kind is None and (path / EVAL_RESULTS).is_file():  # an evaluation written before manifests
        kind = "evaluation"
    if kind == "evaluation":  # its fields as `lhf compare` reads them (the manifest: above)
        if not (path / EVAL_RESULTS).is_file():
            if not any(p.startswith(f"{EVAL_RESULTS}:") for p in problems):
                problems.append(f"{EVAL_RESULTS}: missing")
        else:
            try:
                read_results(path / EVAL_RESULTS)
            except UserError as exc:
                problems.append(str(exc))
    elif artifact is None and kind is None:
        try:
            artifact = artifact_for(path)
        except ValueError:
            raise UserError(
                f"{path} is not an lhf output folder (no {MARKER} and no artifact files)"
            ) from None
        kind = next(k for k, a in CHECKS.items() if a is artifact)
    if artifact is not None:
        problems += artifact.verify(path)
    if kind in FOLDER_CHECKS:
        problems += FOLDER_CHECKS[kind](path)
    return {
        "path": spec if str(path) != spec else str(path),
        "kind": kind,
        "manifest": manifest,
        "notes": notes,
        "problems": problems,
    }


def _snapshot(spec: str) -> Path:
    """The snapshot of a dataset repo, else of a model repo, named ``spec``."""
    errors = []
    for repo_type in ("dataset", "model"):
        try:
            return resolve(spec, repo_type, "artifact")
        except HubError as exc:
            # found, but not what was pushed, or without that revision: that is the answer
            if "not loaded" in str(exc) or ": revision '" in str(exc):
                raise
            errors.append(str(exc))
    raise HubError(f"{spec}: not readable as a dataset repo nor as a model repo; {errors[-1]}")
