"""Documented, validated config dataclasses: the single source of truth of every command."""

from .collect import CollectConfig, PPOSettings, SACSettings
from .evaluate import EvalConfig
from .filter import FilterConfig
from .train import TrainConfig

__all__ = [
    "CollectConfig",
    "EvalConfig",
    "FilterConfig",
    "PPOSettings",
    "SACSettings",
    "TrainConfig",
]
