"""One collator per objective: window items -> exactly the named tensors ``ICRLModel.forward`` takes.

All collators cut the same inputs (docs/design.md 6, token layout in ``modeling_icrl``); they differ in
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

from lhf_hf.errors import UserError
from lhf_hf.modeling import ICRLConfig

from .windows import HistoryArrays


class WindowCollator(ABC):
    """Base: the transition-token inputs and the label mask; subclasses add ``labels``."""

    def __init__(self, arrays: HistoryArrays, config: ICRLConfig, length: int | None = None):
        self.arrays = arrays
        self.config = config
        self.K = config.context_length
        self.length = length or self.K  # transitions per item: K, or a band-attention sequence

    def rows(self, items: list[dict]) -> tuple[np.ndarray, np.ndarray]:
        start = np.fromiter((it["start"] for it in items), np.int64, len(items))  # (B,)
        first_has_prev = np.fromiter((it["has_prev"] for it in items), bool, len(items))  # (B,)
        rows = start[:, None] + np.arange(self.length)  # (B, L)
        has_prev = np.ones(rows.shape, bool)
        has_prev[:, 0] = first_has_prev
        return rows, has_prev

    def __call__(self, items: list[dict]) -> dict[str, torch.Tensor]:
        a = self.arrays
        rows, has_prev = self.rows(items)
        prev = np.maximum(rows - 1, 0)  # (B, L); row -1 only where has_prev is False
        keep = has_prev[..., None] if a.actions.ndim == 2 else has_prev
        batch = {
            "states": torch.from_numpy(a.states[rows]),  # (B, L, S)
            "prev_states": torch.from_numpy(a.states[prev] * has_prev[..., None]),  # (B, L, S)
            "prev_actions": torch.from_numpy(a.actions[prev] * keep),  # (B, L) | (B, L, A)
            "prev_rewards": torch.from_numpy(a.rewards[prev] * has_prev),  # (B, L)
            "prev_dones": torch.from_numpy(a.dones[prev] & has_prev),  # (B, L)
            "has_prev": torch.from_numpy(has_prev),  # (B, L)
        }
        mask = np.ones(rows.shape, bool)
        if self.config.label_positions == "query":
            mask[:, :-1] = False  # the reference AD: one label per window, at the query
        # band attention labels every position too: dropping the labels whose window reaches before
        # the sequence start (so that every label has a full context) lost on Darkroom AD (whole-
        # curve mean 3.46 vs 4.92 with them, docs/training.md): a model must also act well on the
        # short contexts of a rollout's first K steps
        batch["label_mask"] = torch.from_numpy(mask)
        batch.update(self.labels(rows))
        return batch

    @abstractmethod
    def labels(self, rows: np.ndarray) -> dict[str, torch.Tensor]:
        """The objective's targets (and extra inputs) for items of frame ``rows`` (B, L), L = the
        context (windows) or a band-attention sequence."""


class ADCollator(WindowCollator):
    def labels(self, rows):
        return {"action_labels": torch.from_numpy(self.arrays.actions[rows])}  # (B, L)


class DPTCollator(WindowCollator):
    def __init__(self, arrays: HistoryArrays, config: ICRLConfig, length: int | None = None):
        if arrays.optimal_actions is None:
            raise UserError("DPT needs the oracle's optimal actions (column action.optimal)")
        super().__init__(arrays, config, length)

    def labels(self, rows):
        return {"action_labels": torch.from_numpy(self.arrays.optimal_actions[rows])}  # (B, L)


class DICPCollator(WindowCollator):
    def labels(self, rows):
        a = self.arrays
        return {
            "actions": torch.from_numpy(a.actions[rows]),  # (B, L) | (B, L, A)
            "action_labels": torch.from_numpy(a.actions[rows]),
            "reward_labels": torch.from_numpy(a.rewards[rows]),  # (B, L)
            "next_state_labels": torch.from_numpy(a.next_states[rows]),  # (B, L, S) true s'
            "return_labels": torch.from_numpy(a.returns_to_go[rows]),  # (B, L)
        }


COLLATORS: dict[str, type[WindowCollator]] = {
    "ad": ADCollator,
    "dpt": DPTCollator,
    "dicp": DICPCollator,
}


def make_collator(
    arrays: HistoryArrays, config: ICRLConfig, length: int | None = None
) -> WindowCollator:
    """The objective's collator for items of ``length`` transitions (default: the context)."""
    return COLLATORS[config.objective](arrays, config, length)
