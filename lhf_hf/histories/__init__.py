"""Learning-history datasets: LeRobot v3.0 layout plus the lhf extension tables (docs/design.md 4)."""

from .reader import DatasetFormatError, HistoryDataset, load_histories
from .schema import TaskHistories

__all__ = ["DatasetFormatError", "HistoryDataset", "TaskHistories", "load_histories"]
