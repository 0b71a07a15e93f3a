"""Documented, validated config dataclasses: the single source of truth of every command."""

from .collect import CollectConfig, PPOSettings, SACSettings
from .filter import FilterConfig
from .train import TrainConfig

__all__ = ["CollectConfig", "FilterConfig", "PPOSettings", "SACSettings", "TrainConfig"]
