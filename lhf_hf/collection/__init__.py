"""Collect learning histories: SB3 reference collector, recorder, protocols (DESIGN.md 3)."""

from .collect import collect
from .recorder import RecordingVecEnv
from .sb3_collector import collect_task_histories, plan_task

__all__ = ["RecordingVecEnv", "collect", "collect_task_histories", "plan_task"]
