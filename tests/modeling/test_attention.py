"""Band attention: the masks by hand, and the trained function equals the streaming context's."""

from __future__ import annotations

import pytest
import torch

from lhf_hf.evaluation.context import Context, trained_mode
from lhf_hf.modeling import ICRLModel, icrl_config
from lhf_hf.modeling.attention import band_mask, token_windows


def test_band_mask_by_hand():
    m = band_mask(torch.tensor([3, 4]), torch.tensor([2, 3]), torch.tensor([1, 2, 3, 4]))
    ok = torch.tensor([[False, True, True, False], [False, True, True, True]])
    assert torch.equal(m == 0, ok) and torch.isinf(m[~ok]).all()


def test_token_windows_by_hand():
    assert token_windows(4, False, 3).tolist() == [4, 4, 4]
    # DICP: a transition token sees 2K - 1 tokens, its query-action token 2K
    assert token_windows(4, True, 2).tolist() == [7, 8, 7, 8]


def _stream(objective: str, T: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    B = 3
    states = torch.randint(0, 9, (B, T, 2), generator=g)
    actions = torch.randint(0, 5, (B, T), generator=g)
    has_prev = torch.ones(B, T, dtype=torch.bool)
    has_prev[:, 0] = False
    batch = dict(
        states=states,
        prev_states=torch.roll(states, 1, 1),
        prev_actions=torch.roll(actions, 1, 1),
        prev_rewards=(torch.rand(B, T, generator=g) < 0.3).float(),
        prev_dones=torch.rand(B, T, generator=g) < 0.1,
        has_prev=has_prev,
    )
    if objective == "dicp":
        batch["actions"] = actions
    return batch


@torch.no_grad()
@pytest.mark.parametrize("engine", ["lean", "hf"])
@pytest.mark.parametrize("objective", ["ad", "dicp"])
def test_band_trained_function_is_the_streaming_cache(objective, engine):
    """A band-attention forward over a long sequence (what training computes) gives every token the
    same action logits (and DICP heads) as the rollout's streaming KV cache appending the same
    tokens one step at a time: training semantics = test semantics, for a deep (3-layer) model
    whose receptive field is far longer than the window."""
    K, T = 4, 15
    config = icrl_config("tiny", objective=objective, state_dim=2, state_bins=9, action_dim=5,
                         context_length=K, attention="band", num_hidden_layers=3)  # fmt: skip
    torch.manual_seed(0)
    model = ICRLModel(config).eval()
    batch = _stream(objective, T)
    out = model(**batch)
    tokens = model.embed_transitions(
        batch["states"], batch["prev_states"], batch["prev_actions"], batch["prev_rewards"],
        batch["prev_dones"], batch["has_prev"],
    )  # fmt: skip
    ctx = Context(model, mode=trained_mode(model), engine=engine)
    assert ctx.mode == "cache"
    logits, rewards = [], []
    for t in range(T):
        x, is_query = tokens[:, t : t + 1], None
        if objective == "dicp" and t > 0:  # the previous step's query-action token first
            s, a = batch["states"][:, t - 1 : t], batch["actions"][:, t - 1 : t]
            x, is_query = torch.cat([model.embed_query_actions(s, a), x], 1), [True, False]
        hidden = ctx.append(x, is_query)  # (B, n, D)
        if is_query is not None:
            rewards.append(model.dynamics(hidden[:, :1])["reward_pred"])  # (B, 1)
        logits.append(model.action_distribution(hidden[:, -1:])["action_logits"])  # (B, 1, A)
    torch.testing.assert_close(torch.cat(logits, 1), out.action_logits, atol=1e-5, rtol=1e-5)
    if objective == "dicp":
        got = torch.cat(rewards, 1)  # (B, T - 1): the last step's query is never appended
        torch.testing.assert_close(got, out.reward_pred[:, :-1], atol=1e-5, rtol=1e-5)


@torch.no_grad()
def test_window_attention_is_not_the_streaming_cache_and_is_evaluated_by_windows():
    """A window-trained model's function over a long sequence is plain causal attention, which the
    streaming cache does not compute; its evaluation context re-encodes windows instead."""
    config = icrl_config("tiny", objective="ad", state_dim=2, state_bins=9, action_dim=5,
                         context_length=4, num_hidden_layers=2)  # fmt: skip
    model = ICRLModel(config).eval()
    assert config.attention == "window" and trained_mode(model) == "window"
    assert Context(model, mode="auto").mode == "window"
    batch = _stream("ad", 12)
    band = ICRLModel(icrl_config("tiny", objective="ad", state_dim=2, state_bins=9, action_dim=5,
                                 context_length=4, num_hidden_layers=2, attention="band")).eval()  # fmt: skip
    band.load_state_dict(model.state_dict())
    a, b = model(**batch).action_logits, band(**batch).action_logits
    torch.testing.assert_close(a[:, :4], b[:, :4])  # inside the first window: the same function
    assert not torch.allclose(a[:, 4:], b[:, 4:])  # beyond it: different ones


def test_unknown_attention_is_refused():
    with pytest.raises(ValueError, match="ICRLConfig.attention must be one of"):
        icrl_config("tiny", attention="full")
