"""Pretraining of ICRL models: windows, collators per objective, Trainer construction, cards."""

from .collators import COLLATORS, make_collator
from .model_config import check_model_env, model_config_for
from .trainer import build_trainer, train
from .windows import HistoryArrays, WindowDataset, load_arrays, returns_to_go

__all__ = [
    "COLLATORS",
    "HistoryArrays",
    "WindowDataset",
    "build_trainer",
    "check_model_env",
    "load_arrays",
    "make_collator",
    "model_config_for",
    "returns_to_go",
    "train",
]
