"""An LHF selection as a Hub artifact: a dataset repo (selection.parquet + scores + config)."""

from __future__ import annotations

from pathlib import Path

from lhf_hf.histories.reader import HistoryDataset
from lhf_hf.utils.hub import HubArtifact

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
    def card(cls, path: Path, repo_id: str) -> str:
        return render_selection_card(path, repo_id)
