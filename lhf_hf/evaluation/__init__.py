"""In-context evaluation: KV-cached rollouts on unseen tasks, DICP planning, curves and tables."""

from .compare import compare, load_results
from .context import Context
from .evaluate import evaluate, load_model
from .planning import beam_search, greedy_search
from .rollout import RolloutResult, rollout, sample_actions
from .task_batch import BatchedTasks, GymTasks, make_task_batch

__all__ = [
    "BatchedTasks",
    "GymTasks",
    "Context",
    "RolloutResult",
    "beam_search",
    "compare",
    "evaluate",
    "greedy_search",
    "load_model",
    "load_results",
    "make_task_batch",
    "rollout",
    "sample_actions",
]
