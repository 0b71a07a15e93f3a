"""Card templates (README.md of datasets, selections, checkpoints), shipped as package data."""

from __future__ import annotations

from pathlib import Path

from lhf_hf.errors import NotFoundError

#: ``lhf_hf/templates``: package data, so a wheel install renders cards as a checkout does.
TEMPLATES = Path(__file__).resolve().parents[1] / "templates"


def template_path(name: str) -> Path:
    path = TEMPLATES / name
    if not path.exists():
        raise NotFoundError(
            f"card template {path} is missing: the lhf_hf install is incomplete (reinstall it)"
        )
    return path
