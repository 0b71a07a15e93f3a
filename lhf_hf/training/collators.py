"""One collator per objective: window items -> exactly the named tensors ``ICRLModel.forward`` takes.

All collators cut the same inputs (DESIGN.md 6, token layout in ``modeling_icrl``); they differ in
their labels:
- AD: the source's action at each labelled position (paper eq. "AD");
- DPT: the oracle's optimal action of each position's state (paper eq. "DPT", every prefix);
- DICP: AD's labels plus the taken action (query-action token input), reward, true next state and
  return-to-go (paper eq. "DICP").
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
import torch

from lhf_hf.modeling import ICRLConfig

from .windows import HistoryArrays


class WindowCollator(ABC):
    """Base: the transition-token inputs and the label mask; subclasses add ``labels``."""

    def __init__(self, arrays: HistoryArrays, config: ICRLConfig):
        self.arrays = arrays
        self.config = config
        self.K = config.context_length

    def rows(self, items: list[dict]) -> tuple[np.ndarray, np.ndarray]:
        start = np.fromiter((it["start"] for it in items), np.int64, len(items))  # (B,)
        first_has_prev = np.fromiter((it["has_prev"] for it in items), bool, len(items))  # (B,)
        rows = start[:, None] + np.arange(self.K)  # (B, K)
        has_prev = np.ones(rows.shape, bool)
        has_prev[:, 0] = first_has_prev
        return rows, has_prev

    def __call__(self, items: list[dict]) -> dict[str, torch.Tensor]:
        a = self.arrays
        rows, has_prev = self.rows(items)
        prev = np.maximum(rows - 1, 0)  # (B, K); row -1 only where has_prev is False
        keep = has_prev[..., None] if a.actions.ndim == 2 else has_prev
        batch = {
            "states": torch.from_numpy(a.states[rows]),  # (B, K, S)
            "prev_states": torch.from_numpy(a.states[prev] * has_prev[..., None]),  # (B, K, S)
            "prev_actions": torch.from_numpy(a.actions[prev] * keep),  # (B, K) | (B, K, A)
            "prev_rewards": torch.from_numpy(a.rewards[prev] * has_prev),  # (B, K)
            "prev_dones": torch.from_numpy(a.dones[prev] & has_prev),  # (B, K)
            "has_prev": torch.from_numpy(has_prev),  # (B, K)
        }
        mask = np.ones(rows.shape, bool)
        if self.config.label_positions == "query":
            mask[:, :-1] = False  # the reference AD: one label per window, at the query
        batch["label_mask"] = torch.from_numpy(mask)
        batch.update(self.labels(rows))
        return batch

    @abstractmethod
    def labels(self, rows: np.ndarray) -> dict[str, torch.Tensor]:
        """The objective's targets (and extra inputs) for windows of frame ``rows`` (B, K)."""


class ADCollator(WindowCollator):
    def labels(self, rows):
        return {"action_labels": torch.from_numpy(self.arrays.actions[rows])}  # (B, K)


class DPTCollator(WindowCollator):
    def __init__(self, arrays: HistoryArrays, config: ICRLConfig):
        if arrays.optimal_actions is None:
            raise ValueError("DPT needs the oracle's optimal actions (column action.optimal)")
        super().__init__(arrays, config)

    def labels(self, rows):
        return {"action_labels": torch.from_numpy(self.arrays.optimal_actions[rows])}  # (B, K)


class DICPCollator(WindowCollator):
    def labels(self, rows):
        a = self.arrays
        return {
            "actions": torch.from_numpy(a.actions[rows]),  # (B, K) | (B, K, A)
            "action_labels": torch.from_numpy(a.actions[rows]),
            "reward_labels": torch.from_numpy(a.rewards[rows]),  # (B, K)
            "next_state_labels": torch.from_numpy(a.next_states[rows]),  # (B, K, S) true s'
            "return_labels": torch.from_numpy(a.returns_to_go[rows]),  # (B, K)
        }


COLLATORS: dict[str, type[WindowCollator]] = {
    "ad": ADCollator,
    "dpt": DPTCollator,
    "dicp": DICPCollator,
}


def make_collator(arrays: HistoryArrays, config: ICRLConfig) -> WindowCollator:
    return COLLATORS[config.objective](arrays, config)
