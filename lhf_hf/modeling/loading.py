"""``load_model``: an ICRL checkpoint from a local folder or a Hub model repo ``ORG/NAME[@REV]``."""

from __future__ import annotations

from transformers import AutoConfig, AutoModel

from lhf_hf.utils.hub import resolve

from . import modeling_icrl  # noqa: F401  (registers lhf_icrl with AutoConfig / AutoModel)
from .modeling_icrl import ICRLModel


def load_model(path: str) -> ICRLModel:
    """The checkpoint at ``path`` (a folder, or a Hub model repo id), in eval mode."""
    p = resolve(path, "model", "model checkpoint")
    if not (p / "config.json").exists():
        raise FileNotFoundError(
            f"no model checkpoint at {path} (config.json missing; made by `lhf train`)"
        )
    config = AutoConfig.from_pretrained(p)
    if getattr(config, "model_type", None) != "lhf_icrl":
        raise ValueError(
            f"{path} holds a {config.model_type!r} model, not an lhf_icrl (ICRL) model"
        )
    if not any(p.glob("model*.safetensors")):
        if any(p.glob("pytorch_model*.bin")):
            raise ValueError(
                f"{path} holds pickled weights (pytorch_model.bin) only: lhf loads safetensors "
                "alone (unpickling can run code); save the model with save_pretrained(...) "
                "in a Python process you trust to get model.safetensors"
            )
        raise FileNotFoundError(f"{path} has a config.json but no weights (model.safetensors)")
    return AutoModel.from_pretrained(p, use_safetensors=True).eval()
