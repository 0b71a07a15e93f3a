"""A checkpoint of ``lhf train`` as a Hub artifact: a model repo (weights, config, provenance)."""

from __future__ import annotations

import json
from pathlib import Path

from transformers import AutoConfig

from lhf_hf import constants as C
from lhf_hf.errors import UserError
from lhf_hf.histories.artifact import HistoriesArtifact
from lhf_hf.histories.checks import meta_problems
from lhf_hf.histories.reader import HistoryDataset
from lhf_hf.modeling import load_model
from lhf_hf.modeling.remote_code import model_code, with_auto_map
from lhf_hf.utils.hub import HubArtifact
from lhf_hf.utils.io import read_json

from .card import MODEL_EVALS_FILE, evaluation_problems, render_model_card
from .trainer import TRAIN_CONFIG_FILE


class CheckpointArtifact(HubArtifact):
    kind = "checkpoint"
    repo_type = "model"

    @classmethod
    def detect(cls, path: Path) -> bool:
        if not (path / "config.json").exists():
            return False
        model_type = read_json(path / "config.json").get("model_type")
        if model_type != "lhf_icrl":
            raise UserError(f"{path} holds a {model_type!r} model, not an lhf_icrl checkpoint")
        return True

    @classmethod
    def check(cls, path: Path) -> None:
        if not (path / "model.safetensors").exists():
            raise UserError(f"{path}: no weights (model.safetensors)")
        if not (path / TRAIN_CONFIG_FILE).exists():
            raise UserError(f"{path}: {TRAIN_CONFIG_FILE} is missing (a checkpoint of `lhf train`)")
        auto_map = read_json(path / "config.json").get("auto_map") or {}
        missing = sorted(
            {f"{ref.split('.')[0]}.py" for ref in auto_map.values()}
            - {p.name for p in path.glob("*.py")}
        )
        if missing:  # transformers alone could not load it (trust_remote_code)
            raise UserError(
                f"{path}: config.json's auto_map names {', '.join(missing)}, which the folder lacks"
            )
        load_model(str(path))

    @classmethod
    def published(cls, path: Path, source: str | None = None) -> dict[str, bytes]:
        """A checkpoint saved before checkpoints carried their code gets it in the upload, and
        ``auto_map`` in its ``config.json`` (so transformers alone loads the repo); {} otherwise."""
        config = read_json(path / "config.json")
        if config.get("auto_map"):
            return {}
        config = (json.dumps(with_auto_map(config), indent=2, sort_keys=True) + "\n").encode()
        return {"config.json": config} | {n: text.encode() for n, text in model_code().items()}

    @classmethod
    def verify(cls, path: Path) -> list[str]:
        """The checkpoint loads; the dataset it was trained on, when it is a local folder, still
        has the recorded fingerprint."""
        problems = super().verify(path)
        if problems:
            return problems
        evals = path / MODEL_EVALS_FILE  # mutable (evaluations add to it), but must still parse
        if evals.is_file():
            try:
                problems = [f"{evals} {p}" for p in evaluation_problems(read_json(evals))]
            except ValueError as exc:
                return [str(exc)]
            if problems:
                return problems
        try:
            data = read_json(path / TRAIN_CONFIG_FILE).get("dataset") or {}
        except (ValueError, AttributeError) as exc:
            return [f"{path / TRAIN_CONFIG_FILE}: {exc}"]
        source = Path(data.get("path", ""))
        if source.is_dir() and (source / C.INFO_PATH).exists():
            try:
                now = HistoryDataset(source).fingerprint
            except (ValueError, OSError, KeyError) as exc:
                return [f"its dataset {source} no longer opens: {exc}"]
            if now != data.get("fingerprint"):
                return [
                    f"its dataset {source} changed since training (fingerprint "
                    f"{str(data.get('fingerprint'))[:16]} -> {now[:16]})"
                ]
            # the dataset's meta files against its manifest (as every load checks them), then its
            # own deepest check (frames against the fingerprint it records)
            problems = meta_problems(HistoryDataset(source)) + HistoriesArtifact.verify(source)
            return [f"its dataset {source}: {p}" for p in problems]
        return []

    @classmethod
    def card(cls, path: Path, repo_id: str, source: str | None = None) -> str:
        evals = path / MODEL_EVALS_FILE
        return render_model_card(
            AutoConfig.from_pretrained(path, trust_remote_code=False),
            read_json(path / TRAIN_CONFIG_FILE),
            load_path=repo_id,
            evaluations=read_json(evals) if evals.exists() else None,
            public=True,
        )
