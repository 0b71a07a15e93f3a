"""A rollout step's new tokens, embedded in numpy: ``ICRLModel.embed_transitions`` and
``embed_query_actions`` for one token per task, from the numpy arrays the environments return.

Why: the model's embedders build their features with ~25 small torch ops (one-hot encodings, masks,
casts, a concatenation); for 8 tasks and one token that is ~0.25 ms of dispatch per step, a fifth of
an AD rollout step once the decoder is lean (profiled).  Here the same feature vector is
written into one preallocated array by index and multiplied by the same weights.  Where each part
goes is read from the model's config (``ICRLConfig.transition_layout`` / ``query_layout``, the one
definition of the layout); how a state or an action is encoded is written again here in numpy, and the
tests pin it to the model's ``encode_states`` / ``encode_actions`` for integer and real-valued
states, discrete and continuous actions.
"""

from __future__ import annotations

import numpy as np
import torch

from lhf_hf.errors import UserError


class StepTokens:
    """Token embeddings (B, 1, D) of a frozen model (weights copied at construction)."""

    def __init__(self, model) -> None:
        c = model.config
        self.bins, self.S, self.A = c.state_bins, c.state_dim, c.action_dim
        self.discrete = c.discrete_actions
        self.cells = c.cell_encoded
        self.t_layout, self.q_layout = c.transition_layout, c.query_layout  # part -> slice
        self.dtype = model.embed_transition.weight.dtype  # computed in float32, returned in this

        def weights(linear) -> tuple[np.ndarray, np.ndarray]:
            w = linear.weight.detach().float()  # (D, F)
            return np.ascontiguousarray(w.numpy().T), linear.bias.detach().float().numpy()

        self.w_t, self.b_t = weights(model.embed_transition)  # (F, D), (D,)
        self.w_q = self.b_q = None
        if c.objective == "dicp":
            self.w_q, self.b_q = weights(model.embed_query_action)

    def _states(self, out: np.ndarray, states: np.ndarray) -> None:
        """Write the state features of ``states`` (B, S) into ``out`` (B, S'), zero on entry."""
        if not self.bins:
            out[:] = states
            return
        # encode_states: integer coordinates clamped to [0, bins)
        # (np.minimum/np.maximum: np.clip's Python wrapper costs more than the encoding)
        idx = np.minimum(np.maximum(states.astype(np.int64), 0), self.bins - 1)  # (B, S)
        if self.cells:  # one-hot over the cells, row-major
            cell = idx @ (self.bins ** np.arange(self.S - 1, -1, -1))  # (B,)
            out[np.arange(len(states)), cell] = 1.0
        else:  # one-hot per coordinate
            idx += np.arange(self.S) * self.bins
            out[np.arange(len(states))[:, None], idx] = 1.0

    def _actions(self, out: np.ndarray, actions: np.ndarray) -> None:
        """Write the action features of ``actions`` ((B,) ids or (B, A)) into ``out`` (B, A)."""
        if self.discrete:
            ids = np.minimum(np.maximum(actions.astype(np.int64), 0), self.A - 1)  # (B,)
            out[np.arange(len(actions)), ids] = 1.0
        else:
            out[:] = actions

    def transition_features(self, states: np.ndarray, prev: tuple | None) -> np.ndarray:
        """Transition tokens' feature vectors (B, F) for ``states`` (B, S) after ``prev`` = (state,
        action, reward, done) of the step before (None at the start of a stream: those stay 0)."""
        at = self.t_layout
        feats = np.zeros((len(states), self.w_t.shape[0]), np.float32)  # (B, F)
        if prev is not None:
            p_state, p_action, p_reward, p_done = prev
            self._states(feats[:, at["prev_state"]], np.asarray(p_state))
            self._actions(feats[:, at["prev_action"]], np.asarray(p_action))
            feats[:, at["prev_reward"]] = np.reshape(p_reward, (-1, 1))  # (B, 1)
            feats[:, at["prev_done"]] = np.reshape(p_done, (-1, 1))
            feats[:, at["has_prev"]] = 1.0
        self._states(feats[:, at["state"]], np.asarray(states))
        return feats

    def transition(self, states: np.ndarray, prev: tuple | None) -> torch.Tensor:
        """Transition tokens (B, 1, D); arguments as ``transition_features``."""
        return self._out(self.transition_features(states, prev) @ self.w_t + self.b_t)

    def query_features(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """DICP query-action tokens' feature vectors (B, F) for the action taken in each state."""
        if self.q_layout is None:
            raise UserError("query-action tokens exist for DICP models only")
        at = self.q_layout
        feats = np.zeros((len(states), self.w_q.shape[0]), np.float32)  # (B, F)
        self._states(feats[:, at["state"]], np.asarray(states))
        self._actions(feats[:, at["action"]], np.asarray(actions))
        return feats

    def query(self, states: np.ndarray, actions: np.ndarray) -> torch.Tensor:
        """DICP query-action tokens (B, 1, D) for the action taken in each state."""
        return self._out(self.query_features(states, actions) @ self.w_q + self.b_q)

    def _out(self, tokens: np.ndarray) -> torch.Tensor:
        t = torch.from_numpy(tokens[:, None])  # (B, D) -> (B, 1, D)
        return t if self.dtype == torch.float32 else t.to(self.dtype)
