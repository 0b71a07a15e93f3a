"""Collect learning histories: SB3 reference collector, recorder, protocols (docs/design.md 3).

The names below are imported on first use (PEP 562), so that ``lhf_hf.collection.ppo_backends``
imports with torch alone (e.g. on a GPU machine without Stable-Baselines3 or ``datasets``).
"""

from importlib import import_module

_EXPORTS = {
    "collect": ".driver",
    "RecordingVecEnv": ".recorder",
    "collect_task_histories": ".sb3_collector",
    "plan_task": ".sb3_collector",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(import_module(_EXPORTS[name], __name__), name)
        globals()[name] = value  # looked up once
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
