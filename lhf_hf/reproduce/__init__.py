"""Reproduce the paper's experiments end to end (``lhf reproduce``; issue 8)."""

from .experiment import Experiment, experiment_names, load_experiment
from .reproduce import estimate_experiment, export_experiment, plan_stages, reproduce

__all__ = [
    "Experiment",
    "estimate_experiment",
    "export_experiment",
    "experiment_names",
    "load_experiment",
    "plan_stages",
    "reproduce",
]
