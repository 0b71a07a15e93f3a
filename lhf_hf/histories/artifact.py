"""A learning-history dataset as a Hub artifact: a dataset repo tagged with the codebase version."""

from __future__ import annotations

from pathlib import Path

from lhf_hf import constants as C
from lhf_hf.utils.hub import HubArtifact

from .card import render_card
from .checks import check_dataset
from .reader import HistoryDataset


class HistoriesArtifact(HubArtifact):
    kind = "histories"
    repo_type = "dataset"
    # LeRobot's loaders resolve a dataset's codebase version through this git tag.
    tag = C.CODEBASE_VERSION

    @classmethod
    def detect(cls, path: Path) -> bool:
        return (path / C.INFO_PATH).exists()

    @classmethod
    def check(cls, path: Path) -> None:
        HistoryDataset(path).data_files()

    @classmethod
    def verify(cls, path: Path) -> list[str]:
        """Every data file hashed against the fingerprint; every task's returns recomputed (the
        manifest is its caller's: ``lhf verify`` and ``lhf push`` check every file of it)."""
        try:
            return check_dataset(HistoryDataset(path), full=True)
        except (ValueError, OSError, KeyError) as exc:
            return [str(exc)]

    @classmethod
    def card(cls, path: Path, repo_id: str, source: str | None = None) -> str:
        return render_card(HistoryDataset(path), load_path=repo_id)
