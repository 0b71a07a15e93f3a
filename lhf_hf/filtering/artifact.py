"""An LHF selection as a Hub artifact: a dataset repo (selection.parquet + scores + config)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

from lhf_hf import constants as C
from lhf_hf.histories.reader import HistoryDataset
from lhf_hf.utils.hub import HubArtifact, HubError, download, parse_hub_ref
from lhf_hf.utils.io import read_json

from .card import render_selection_card
from .select import CONFIG_FILE, load_selection, source_mismatch


class SelectionArtifact(HubArtifact):
    kind = "selection"
    repo_type = "dataset"

    @classmethod
    def detect(cls, path: Path) -> bool:
        return (path / CONFIG_FILE).exists()

    @classmethod
    def check(cls, path: Path) -> None:
        load_selection(path)

    @classmethod
    def verify(cls, path: Path) -> list[str]:
        """The selection opens; its source dataset, when it is a local folder, is still the one
        it was computed from."""
        try:
            sel = load_selection(path)
            source = Path(sel.source.get("path", ""))
            if not source.is_dir():
                return []
            return source_mismatch(HistoryDataset(source), sel)
        except (ValueError, OSError, KeyError) as exc:
            return [str(exc)]

    @classmethod
    def pin_source(cls, path: Path, source_repo: str) -> str:
        """The source dataset's repo at the commit it holds now, once its fingerprints (frames and
        histories table) are the ones the selection recorded: a card never names data the
        selection was not computed from."""
        ref = parse_hub_ref(source_repo)
        if ref is None:
            raise HubError(
                f"--source-repo {source_repo!r} is not a Hub repo id ORG/NAME[@REVISION]"
            )
        snapshot = download(ref, "dataset", files=[C.LHF_INFO_PATH, C.HISTORIES_PATH])
        pinned = f"{ref.repo_id}@{snapshot.name}"
        if (
            not (snapshot / C.LHF_INFO_PATH).is_file()
            or not (snapshot / C.HISTORIES_PATH).is_file()
        ):
            raise HubError(
                f"{pinned} is not an lhf history dataset (no {C.LHF_INFO_PATH}): not pushed"
            )
        pushed = SimpleNamespace(
            root=snapshot, fingerprint=read_json(snapshot / C.LHF_INFO_PATH).get("fingerprint")
        )
        problems = source_mismatch(pushed, load_selection(path))
        if problems:
            raise HubError(
                f"{pinned} is not the dataset {path} was computed from ({problems[0]}); not pushed"
            )
        return pinned

    @classmethod
    def card(cls, path: Path, repo_id: str, source: str | None = None) -> str:
        return render_selection_card(path, repo_id, source=source)

    @classmethod
    def published(cls, path: Path, source: str | None = None) -> dict[str, bytes]:
        """With a pinned source, the pushed record names it in place of this machine's folder."""
        if source is None:
            return {}
        record = read_json(path / CONFIG_FILE)
        record["source"]["path"] = source
        return {CONFIG_FILE: (json.dumps(record, indent=2) + "\n").encode()}
