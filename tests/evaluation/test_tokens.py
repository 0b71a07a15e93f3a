"""The rollout's numpy token embedder: its feature vectors by hand (the layout of
``ICRLConfig.transition_layout``, as in ``tests/modeling/test_token_layout.py``), and its tokens equal
to the model's own embedders (``modeling_icrl.py``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lhf_hf.evaluation.tokens import StepTokens
from lhf_hf.modeling import ICRLModel, icrl_config

CASES = {
    # integer grid states (one-hot per coordinate, out-of-range coordinates clamped), discrete actions
    "grid": dict(state_dim=2, state_bins=9, action_dim=5, discrete_actions=True),
    # the same states as one cell one-hot (row-major, out-of-range coordinates clamped)
    "cells": dict(
        state_dim=2, state_bins=9, state_encoding="cells", action_dim=5, discrete_actions=True
    ),
    # real-valued states, continuous actions (Meta-World)
    "continuous": dict(state_dim=6, state_bins=0, action_dim=4, discrete_actions=False),
}


def _batch(case: str, rng: np.random.Generator, B: int = 7):
    c = CASES[case]
    if c["state_bins"]:
        states = rng.integers(-1, 11, (B, c["state_dim"])).astype(np.float32)  # some out of range
        actions = rng.integers(0, c["action_dim"], B)
    else:
        states = rng.standard_normal((B, c["state_dim"])).astype(np.float32)
        actions = rng.uniform(-1, 1, (B, c["action_dim"])).astype(np.float32)
    return states, actions


@torch.no_grad()
@pytest.mark.parametrize("case", sorted(CASES))
def test_step_tokens_equal_the_model_embedders(case):
    model = ICRLModel(icrl_config("tiny", objective="dicp", **CASES[case])).eval()
    tokens = StepTokens(model)
    rng = np.random.default_rng(0)
    states, _ = _batch(case, rng)
    p_state, p_action = _batch(case, rng)
    p_reward = rng.standard_normal(len(states))  # float64, as the environments return them
    p_done = rng.random(len(states)) < 0.5
    B = len(states)

    def t(x, dtype=None):
        x = torch.as_tensor(x)[:, None]
        return x if dtype is None else x.to(dtype)

    for prev in (None, (p_state, p_action, p_reward, p_done)):
        has = prev is not None
        ps, pa, pr, pd = prev if has else (np.zeros_like(p_state), p_action, p_reward, p_done)
        want = model.embed_transitions(
            states=t(states),
            prev_states=t(ps),
            prev_actions=t(pa),
            prev_rewards=t(pr, torch.float32),
            prev_dones=t(pd),
            has_prev=torch.full((B, 1), has),
        )  # (B, 1, D)
        got = tokens.transition(states, prev)
        assert got.shape == want.shape and got.dtype == want.dtype
        torch.testing.assert_close(got, want, atol=1e-6, rtol=1e-6)
    want = model.embed_query_actions(t(p_state), t(p_action))
    torch.testing.assert_close(tokens.query(p_state, p_action), want, atol=1e-6, rtol=1e-6)


def test_step_features_by_hand():
    """Darkroom, one-hot per coordinate: the step (2, 7) --action 3, reward 1, done--> then state
    (8, 0), and the first token of a stream (nothing before it)."""
    model = ICRLModel(icrl_config("tiny", objective="dicp", **CASES["grid"])).eval()
    tokens = StepTokens(model)
    states = np.array([[8.0, 0.0]], np.float32)
    want = np.zeros((1, 44), np.float32)
    want[0, [2, 9 + 7]] = 1  # prev_state (2, 7): row one-hot, then column one-hot
    want[0, 18 + 3] = 1  # prev_action 3
    want[0, [23, 24, 25]] = 1.0  # prev_reward, prev_done, has_prev
    want[0, [26 + 8, 26 + 9 + 0]] = 1  # state (8, 0)
    prev = (np.array([[2.0, 7.0]]), np.array([3]), np.array([1.0]), np.array([True]))
    np.testing.assert_array_equal(tokens.transition_features(states, prev), want)
    first = np.zeros((1, 44), np.float32)
    first[0, [26 + 8, 26 + 9]] = 1
    np.testing.assert_array_equal(tokens.transition_features(states, None), first)
    query = np.zeros((1, 23), np.float32)
    query[0, [8, 9 + 0, 18 + 2]] = 1  # state (8, 0), action 2
    np.testing.assert_array_equal(tokens.query_features(states, np.array([2])), query)

    cont = dict(state_dim=2, state_bins=0, action_dim=2, discrete_actions=False)
    tokens = StepTokens(ICRLModel(icrl_config("tiny", objective="ad", **cont)).eval())
    prev = (np.array([[2.0, 3.0]]), np.array([[0.25, -0.75]]), np.array([-0.5]), np.array([False]))
    got = tokens.transition_features(np.array([[0.5, -1.5]], np.float32), prev)
    assert got.tolist() == [[2.0, 3.0, 0.25, -0.75, -0.5, 0.0, 1.0, 0.5, -1.5]]


def test_query_tokens_need_a_dicp_model():
    model = ICRLModel(icrl_config("tiny", objective="ad", **CASES["grid"])).eval()
    with pytest.raises(ValueError, match="DICP models only"):
        StepTokens(model).query(np.zeros((1, 2)), np.zeros(1))
