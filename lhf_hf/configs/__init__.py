"""Documented, validated config dataclasses: the single source of truth of every command."""

from .collect import CollectConfig, PPOSettings, SACSettings

__all__ = ["CollectConfig", "PPOSettings", "SACSettings"]
