"""Collect learning histories (docs/design.md 3): ``collect`` (``driver.py``: tasks in worker
processes, resume, the dataset's writer) runs the batched collector (``batched_collector.py``, the
stacked PPO of ``batched_ppo.py`` / the C++ kernel of ``native.py``) or the SB3 reference
(``sb3_collector.py``: the protocols as learner plans, ``recorder.py``).

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
