"""``load_model``: an ICRL checkpoint from a local folder or a Hub model repo ``ORG/NAME[@REV]``."""

from __future__ import annotations

from pathlib import Path

from safetensors import SafetensorError, safe_open
from transformers import AutoConfig, AutoModel

from lhf_hf.errors import NotFoundError, UserError
from lhf_hf.utils.hub import resolve

from .modeling_icrl import ICRLModel


def load_model(path: str) -> ICRLModel:
    """The checkpoint at ``path`` (a folder, or a Hub model repo id), in eval mode."""
    p = resolve(path, "model", "model checkpoint")
    if not (p / "config.json").exists():
        raise NotFoundError(
            f"no model checkpoint at {path} (config.json missing; made by `lhf train`)"
        )
    try:
        # lhf_hf's own classes, never the code a checkpoint carries beside its weights
        config = AutoConfig.from_pretrained(p, trust_remote_code=False)
    except (OSError, ValueError, TypeError) as exc:  # transformers: OSError for malformed JSON
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise UserError(f"{p / 'config.json'} is not a readable model config ({why})") from None
    if getattr(config, "model_type", None) != "lhf_icrl":
        raise UserError(f"{path} holds a {config.model_type!r} model, not an lhf_icrl (ICRL) model")
    if not any(p.glob("model*.safetensors")):
        if any(p.glob("pytorch_model*.bin")):
            raise UserError(
                f"{path} holds pickled weights (pytorch_model.bin) only: lhf loads safetensors "
                "alone (unpickling can run code); save the model with save_pretrained(...) "
                "in a Python process you trust to get model.safetensors"
            )
        raise NotFoundError(f"{path} has a config.json but no weights (model.safetensors)")
    check_weights(p, config)
    model = AutoModel.from_pretrained(p, use_safetensors=True, trust_remote_code=False).eval()
    bad = [
        n for n, t in model.state_dict().items() if t.is_floating_point() and not t.isfinite().all()
    ]
    if bad:  # a diverged training: its actions would be NaN draws, not a policy
        raise UserError(
            f"{path}: {len(bad)} weight tensors hold NaN or infinite values (e.g. {bad[0]}): "
            "not a usable model"
        )
    return model


def check_weights(folder: Path, config) -> None:
    """Refuse weights that do not fit ``config`` exactly: a missing, unexpected or mis-shaped
    tensor, or an unreadable file.

    ``from_pretrained`` would initialise a missing head at random and carry on (a DICP config over
    AD weights evaluates random reward heads), so every tensor is checked against the model the
    config builds before anything loads.
    """
    expected = {k: tuple(v.shape) for k, v in ICRLModel(config).state_dict().items()}
    found: dict[str, tuple] = {}
    for file in sorted(folder.glob("model*.safetensors")):
        try:
            with safe_open(str(file), framework="pt") as f:
                for k in f.keys():  # noqa: SIM118 (safe_open is not a mapping)
                    found[k] = tuple(f.get_slice(k).get_shape())
        except (SafetensorError, OSError, ValueError) as e:
            raise UserError(f"{file}: not a readable safetensors file ({e})") from None
    missing = sorted(set(expected) - set(found))
    unexpected = sorted(set(found) - set(expected))
    misshaped = sorted(
        f"{k} {list(found[k])} (config: {list(expected[k])})"
        for k in set(found) & set(expected)
        if found[k] != expected[k]
    )
    problems = [
        *([f"missing {_names(missing)}"] if missing else []),
        *([f"unexpected {_names(unexpected)}"] if unexpected else []),
        *([f"mis-shaped {_names(misshaped)}"] if misshaped else []),
    ]
    if problems:
        raise UserError(
            f"{folder}: the weights do not fit its config.json ({config.objective}, "
            f"{config.num_hidden_layers} layers, hidden {config.hidden_size}): "
            + "; ".join(problems)
        )


def _names(items: list[str], shown: int = 4) -> str:
    more = f" and {len(items) - shown} more" if len(items) > shown else ""
    return ", ".join(items[:shown]) + more
