"""The token layout, defined once (``ICRLConfig.transition_layout`` / ``query_layout``): the slices
by hand for AD / DPT / DICP on integer and real-valued states, and the model's feature vectors, part by
part, against vectors written by hand.  (The rollout's numpy embedder is checked against the same hand
vectors in ``tests/evaluation/test_tokens.py``.)"""

from __future__ import annotations

import pytest
import torch

from lhf_hf.modeling import ICRLModel, icrl_config
from lhf_hf.modeling.configuration_icrl import QUERY_FEATURES, TRANSITION_FEATURES

GRID = dict(state_dim=2, state_bins=9, action_dim=5, discrete_actions=True)  # darkroom
CELLS = dict(GRID, state_encoding="cells")
CONTINUOUS = dict(state_dim=39, state_bins=0, action_dim=4, discrete_actions=False)  # Meta-World


def _slices(*widths):
    out, start = [], 0
    for w in widths:
        out.append(slice(start, start + w))
        start += w
    return out


# (space, state features S', action features A): transition token [s, a, r, d, has_prev, s'],
# query-action token [s, a]
SPACES = {"grid": (GRID, 2 * 9, 5), "cells": (CELLS, 81, 5), "continuous": (CONTINUOUS, 39, 4)}


# DPT labels the oracle's action: gridworlds (discrete actions) only
CASES = [
    (s, o) for s in sorted(SPACES) for o in ("ad", "dpt", "dicp") if (s, o) != ("continuous", "dpt")
]


@pytest.mark.parametrize("space, objective", CASES)
def test_layouts_by_hand(space, objective):
    fields, s, a = SPACES[space]
    config = icrl_config("tiny", objective=objective, **fields)
    assert config.state_features == s
    assert list(config.transition_layout) == list(TRANSITION_FEATURES)
    assert list(config.transition_layout.values()) == _slices(s, a, 1, 1, 1, s)
    model = ICRLModel(config)
    assert model.embed_transition.in_features == 2 * s + a + 3
    if objective != "dicp":
        assert config.query_layout is None and not hasattr(model, "embed_query_action")
        return
    assert list(config.query_layout) == list(QUERY_FEATURES)
    assert list(config.query_layout.values()) == _slices(s, a)
    assert model.embed_query_action.in_features == s + a
    assert model.next_state_head.out_features == s  # one logit per cell / coordinate bin, or S


def test_darkroom_features_by_hand():
    """Darkroom, one-hot per coordinate: the step (2, 7) --action 3, reward 1, done--> then state
    (8, 0), and the first token of a history (nothing before it)."""
    model = ICRLModel(icrl_config("tiny", objective="dicp", **GRID))
    want = torch.zeros(2 * 18 + 5 + 3)
    want[2] = want[9 + 7] = 1  # prev_state (2, 7): row one-hot, then column one-hot
    want[18 + 3] = 1  # prev_action 3
    want[23], want[24], want[25] = 1.0, 1.0, 1.0  # prev_reward, prev_done, has_prev
    want[26 + 8] = want[26 + 9 + 0] = 1  # state (8, 0)
    first = torch.zeros(44)
    first[26 + 4] = first[26 + 9 + 4] = 1  # state (4, 4) only

    got = model.transition_features(
        states=torch.tensor([[[8, 0], [4, 4]]]),
        prev_states=torch.tensor([[[2, 7], [5, 5]]]),
        prev_actions=torch.tensor([[3, 1]]),
        prev_rewards=torch.tensor([[1.0, 1.0]]),
        prev_dones=torch.tensor([[True, True]]),
        has_prev=torch.tensor([[True, False]]),
    )  # (1, 2, 44)
    assert torch.equal(got[0, 0], want) and torch.equal(got[0, 1], first)
    query = torch.zeros(18 + 5)
    query[8] = query[9 + 0] = query[18 + 2] = 1  # state (8, 0), action 2
    got = model.query_features(torch.tensor([[[8, 0]]]), torch.tensor([[2]]))  # (1, 1, 23)
    assert torch.equal(got[0, 0], query)


def test_cells_and_continuous_features_by_hand():
    cells = ICRLModel(icrl_config("tiny", objective="ad", **CELLS))
    got = cells.transition_features(
        states=torch.tensor([[[8, 0]]]),
        prev_states=torch.tensor([[[2, 7]]]),
        prev_actions=torch.tensor([[4]]),
        prev_rewards=torch.tensor([[0.0]]),
        prev_dones=torch.tensor([[False]]),
        has_prev=torch.tensor([[True]]),
    )[0, 0]  # (170,)
    want = torch.zeros(81 + 5 + 3 + 81)
    want[2 * 9 + 7] = want[81 + 4] = want[88] = want[89 + 8 * 9 + 0] = 1  # cells 25 and 72
    assert torch.equal(got, want)

    fields = dict(CONTINUOUS, state_dim=2, action_dim=2)
    cont = ICRLModel(icrl_config("tiny", objective="dicp", **fields))
    got = cont.transition_features(
        states=torch.tensor([[[0.5, -1.5]]]),
        prev_states=torch.tensor([[[2.0, 3.0]]]),
        prev_actions=torch.tensor([[[0.25, -0.75]]]),
        prev_rewards=torch.tensor([[-0.5]]),
        prev_dones=torch.tensor([[False]]),
        has_prev=torch.tensor([[True]]),
    )[0, 0]
    assert got.tolist() == [2.0, 3.0, 0.25, -0.75, -0.5, 0.0, 1.0, 0.5, -1.5]
    got = cont.query_features(torch.tensor([[[0.5, -1.5]]]), torch.tensor([[[1.0, 0.0]]]))
    assert got[0, 0].tolist() == [0.5, -1.5, 1.0, 0.0]
