"""ICRL model: causality, no label leakage, losses against reference formulas, cache, save/load."""

from __future__ import annotations

import math

import pytest
import torch
from transformers import AutoConfig, AutoModel

from lhf_hf.modeling import ICRLConfig, ICRLModel, icrl_config

B, T = 2, 12


def grid_config(objective="ad", **kw):
    return icrl_config(
        "tiny", objective=objective, state_dim=2, state_bins=9, action_dim=5, context_length=T, **kw
    )


def cont_config(objective="ad", **kw):
    return icrl_config(
        "tiny",
        objective=objective,
        state_dim=3,
        state_bins=0,
        action_dim=2,
        discrete_actions=False,
        context_length=T,
        **kw,
    )


def make_batch(config: ICRLConfig, seed=0):
    g = torch.Generator().manual_seed(seed)
    S, A = config.state_dim, config.action_dim
    if config.state_bins:
        states = torch.randint(0, config.state_bins, (B, T, S), generator=g)
        prev_states = torch.randint(0, config.state_bins, (B, T, S), generator=g)
    else:
        states, prev_states = torch.randn(B, T, S, generator=g), torch.randn(B, T, S, generator=g)
    if config.discrete_actions:
        actions = torch.randint(0, A, (B, T), generator=g)
        prev_actions = torch.randint(0, A, (B, T), generator=g)
    else:
        actions, prev_actions = (
            torch.rand(B, T, A, generator=g) * 2 - 1,
            torch.rand(B, T, A, generator=g) * 2 - 1,
        )
    has_prev = torch.ones(B, T, dtype=torch.bool)
    has_prev[0, 0] = False
    batch = dict(
        states=states,
        prev_states=prev_states,
        prev_actions=prev_actions,
        prev_rewards=torch.rand(B, T, generator=g),
        prev_dones=torch.rand(B, T, generator=g) < 0.2,
        has_prev=has_prev,
    )
    if config.objective == "dicp":
        batch["actions"] = actions
    return batch, actions


def model_for(config, seed=0):
    torch.manual_seed(seed)
    return ICRLModel(config).eval()


def outputs(model, batch):
    with torch.no_grad():
        out = model(**batch)
    keys = (
        "action_logits",
        "action_mean",
        "reward_pred",
        "next_state_logits",
        "next_state_pred",
        "return_pred",
    )
    return {k: out[k] for k in keys if out.get(k) is not None}


@pytest.mark.parametrize(
    "make, objective",
    [
        (grid_config, "ad"),
        (grid_config, "dpt"),
        (grid_config, "dicp"),
        (cont_config, "ad"),
        (cont_config, "dicp"),
    ],
)
def test_causal_later_tokens_do_not_change_earlier_outputs(make, objective):
    config = make(objective)
    model = model_for(config)
    batch, _ = make_batch(config)
    base = outputs(model, batch)
    j = 7
    changed, _ = make_batch(config, seed=1)
    batch2 = {k: v.clone() for k, v in batch.items()}
    for k, v in changed.items():  # replace every input from position j on
        batch2[k][:, j:] = v[:, j:]
    new = outputs(model, batch2)
    for k in base:
        torch.testing.assert_close(new[k][:, :j], base[k][:, :j], msg=k)
        assert not torch.allclose(new[k][:, j:], base[k][:, j:]), k


def test_dicp_policy_does_not_see_its_own_action():
    """The action logits at j come from T_j, which precedes the query-action token Q_j = [s_j, a_j]."""
    config = grid_config("dicp")
    model = model_for(config)
    batch, _ = make_batch(config)
    base = outputs(model, batch)
    batch["actions"] = (batch["actions"] + 1) % 5
    new = outputs(model, batch)
    torch.testing.assert_close(new["action_logits"][:, 0], base["action_logits"][:, 0])
    # position 0's dynamics heads read Q_0, which holds a_0: they must change
    assert not torch.allclose(new["reward_pred"][:, 0], base["reward_pred"][:, 0])


def test_missing_previous_step_is_ignored():
    config = grid_config()
    model = model_for(config)
    batch, _ = make_batch(config)
    base = outputs(model, batch)
    batch["prev_states"][0, 0] += 3  # has_prev[0, 0] is False: must not matter
    batch["prev_actions"][0, 0] = (batch["prev_actions"][0, 0] + 1) % 5
    batch["prev_rewards"][0, 0] = 7.0
    torch.testing.assert_close(outputs(model, batch)["action_logits"], base["action_logits"])


def test_discrete_action_loss_is_masked_cross_entropy():
    config = grid_config()
    model = model_for(config)
    batch, actions = make_batch(config)
    mask = torch.zeros(B, T, dtype=torch.bool)
    mask[:, -1] = True
    mask[1, 3] = True
    out = model(**batch, action_labels=actions, label_mask=mask)
    logp = torch.log_softmax(out.action_logits, -1)
    picked = logp.gather(-1, actions.unsqueeze(-1)).squeeze(-1)  # (B, T)
    torch.testing.assert_close(out.loss, -picked[mask].mean())


def test_gaussian_action_loss_matches_torch_normal():
    config = cont_config()
    model = model_for(config)
    batch, actions = make_batch(config)
    out = model(**batch, action_labels=actions)
    normal = torch.distributions.Normal(out.action_mean, out.action_log_std.exp())
    torch.testing.assert_close(out.loss, -normal.log_prob(actions).sum(-1).mean())


@pytest.mark.parametrize("make", [grid_config, cont_config])
def test_dicp_loss_is_action_plus_xi_times_dynamics(make):
    config = make("dicp", dynamics_coef=0.5, return_scale=20.0)
    model = model_for(config)
    batch, actions = make_batch(config)
    g = torch.Generator().manual_seed(3)
    rewards = torch.rand(B, T, generator=g)
    returns = torch.rand(B, T, generator=g) * 20
    if config.state_bins:
        nxt = torch.randint(0, 9, (B, T, 2), generator=g)
    else:
        nxt = torch.randn(B, T, 3, generator=g)
    out = model(
        **batch,
        action_labels=actions,
        reward_labels=rewards,
        next_state_labels=nxt,
        return_labels=returns,
    )
    reward_mse = ((out.reward_pred - rewards) ** 2).mean()
    return_mse = ((out.return_pred - returns / 20.0) ** 2).mean()
    if config.state_bins:
        logp = torch.log_softmax(out.next_state_logits, -1)  # (B, T, S, bins)
        state = -logp.gather(-1, nxt.unsqueeze(-1)).mean()
    else:
        state = ((out.next_state_pred - nxt) ** 2).mean()
    torch.testing.assert_close(out.dynamics_loss, reward_mse + state + return_mse)
    torch.testing.assert_close(out.loss, out.action_loss + 0.5 * out.dynamics_loss)


def test_incremental_cache_equals_full_forward():
    """Running a window in two chunks with the KV cache gives the full forward's outputs."""
    config = grid_config()
    model = model_for(config)
    batch, _ = make_batch(config)
    full = outputs(model, batch)["action_logits"]
    first = {k: v[:, :5] for k, v in batch.items()}
    rest = {k: v[:, 5:] for k, v in batch.items()}
    with torch.no_grad():
        a = model(**first, use_cache=True)
        b = model(**rest, backbone_cache=a.backbone_cache, use_cache=True)
    torch.testing.assert_close(torch.cat([a.action_logits, b.action_logits], 1), full)


def test_cached_forward_raises_no_deprecation(caplog):
    """The backbone's KV cache travels under the name the installed transformers owns
    (``past_key_values`` up to 5.23, ``cache`` from 5.24): no deprecation warning, no log line."""
    import warnings

    from transformers.utils import logging as hf_logging

    config = grid_config()
    model = model_for(config)
    batch, _ = make_batch(config)
    first = {k: v[:, :5] for k, v in batch.items()}
    rest = {k: v[:, 5:] for k, v in batch.items()}
    hf_logging.get_logger("x").warning_once.__func__.cache_clear()  # warnings logged "once" re-log
    with warnings.catch_warnings(record=True) as caught, torch.no_grad():
        warnings.simplefilter("always")
        a = model(**first, use_cache=True)
        b = model(**rest, backbone_cache=a.backbone_cache, use_cache=True)
    assert b.backbone_cache is a.backbone_cache and b.backbone_cache.get_seq_length() == T
    assert not [w for w in caught if issubclass(w.category, (DeprecationWarning, FutureWarning))], [
        str(w.message) for w in caught
    ]
    assert "deprecated" not in caplog.text


@pytest.mark.slow
def test_save_load_identical_outputs(tmp_path):
    config = grid_config("dicp")
    model = model_for(config)
    batch, _ = make_batch(config)
    model.save_pretrained(tmp_path / "m")
    assert (tmp_path / "m" / "model.safetensors").exists()
    loaded = AutoModel.from_pretrained(tmp_path / "m").eval()
    assert isinstance(loaded, ICRLModel) and loaded.config.objective == "dicp"
    for k, v in outputs(model, batch).items():
        torch.testing.assert_close(outputs(loaded, batch)[k], v, rtol=0, atol=0)
    assert isinstance(AutoConfig.for_model("lhf_icrl"), ICRLConfig)


def test_presets_have_paper_sizes():
    c = icrl_config("paper")
    assert (c.num_hidden_layers, c.num_attention_heads, c.hidden_size, c.intermediate_size) == (
        4,
        4,
        32,
        128,
    )
    assert c.attention_dropout == c.embedding_dropout == 0.1
    c = icrl_config("lightweight")
    assert (c.num_hidden_layers, c.num_attention_heads, c.hidden_size, c.intermediate_size) == (
        2,
        2,
        16,
        64,
    )
    assert icrl_config("paper", objective="dicp").max_tokens == 2 * 80
    assert math.isclose(icrl_config("paper").rope_parameters["rope_theta"], 10000.0)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(objective="ppo"), "objective"),
        (dict(label_positions="some"), "label_positions"),
        (dict(objective="dpt", label_positions="query"), "every prefix"),
        (dict(state_bins=1), "state_bins"),
        (dict(context_length=0), "context_length"),
        (dict(dynamics_coef=-1.0), "dynamics_coef"),
    ],
)
def test_config_rejects_bad_values(kw, match):
    with pytest.raises(ValueError, match=match):
        ICRLConfig(**kw)
    with pytest.raises(ValueError, match="unknown model preset"):
        icrl_config("huge")


def test_dicp_forward_needs_actions():
    config = grid_config("dicp")
    batch, _ = make_batch(config)
    batch.pop("actions")
    with pytest.raises(ValueError, match="actions"):
        model_for(config)(**batch)


def test_a_mistyped_input_is_refused_not_dropped():
    # a collator key with a typo (reward_label for reward_labels) must not train without its loss
    config = grid_config("dicp")
    batch, _ = make_batch(config)
    batch["reward_label"] = torch.zeros(batch["states"].shape[:2])
    with pytest.raises(TypeError, match="reward_label"):
        model_for(config)(**batch)


@pytest.mark.parametrize(
    "fields, field",
    [
        ({"objective": "bc"}, "objective"),
        ({"objective": "dpt", "label_positions": "query"}, "label_positions"),
        ({"objective": "ad", "label_positions": "every"}, "label_positions"),
        ({"objective": "ad", "context_length": 0}, "context_length"),
        ({"objective": "dicp", "dynamics_coef": -1.0}, "dynamics_coef"),
    ],
)
def test_train_config_and_model_config_share_the_model_rules(fields, field):
    """TrainConfig refuses what ICRLConfig refuses, with the same message (one set of rules)."""
    from lhf_hf.configs import TrainConfig

    with pytest.raises(ValueError, match=f"ICRLConfig.{field} ") as model_err:
        icrl_config("tiny", **fields)
    with pytest.raises(ValueError, match=f"TrainConfig.{field} ") as train_err:
        TrainConfig(dataset="d", out="o", **fields)
    assert str(model_err.value).split(" ", 1)[1] == str(train_err.value).split(" ", 1)[1]


def labelled_dicp_batch(B: int, T: int, same_next_states: bool) -> dict:
    """A DICP batch on a 9 x 9 grid with 0/1 rewards and every label (rewards double as returns;
    the next states are the states themselves or drawn independently)."""
    g = torch.Generator().manual_seed(1)
    states = torch.randint(0, 9, (B, T, 2), generator=g)
    nxt = states if same_next_states else torch.randint(0, 9, (B, T, 2), generator=g)
    actions = torch.randint(0, 5, (B, T), generator=g)
    rewards = (torch.rand(B, T, generator=g) < 0.3).float()
    return dict(states=states, prev_states=states, prev_actions=actions, prev_rewards=rewards,
                prev_dones=torch.zeros(B, T, dtype=torch.bool), has_prev=torch.ones(B, T, dtype=torch.bool),
                actions=actions, action_labels=actions, reward_labels=rewards,
                next_state_labels=nxt, return_labels=rewards)  # fmt: skip


def test_categorical_reward_head_loss_prediction_and_round_trip(tmp_path):
    """With reward classes the head classifies (cross-entropy, by hand), predicts the most likely
    class's value, refuses rewards that are none of the classes, and survives save/load."""
    import torch.nn.functional as F

    config = icrl_config("tiny", objective="dicp", state_dim=2, state_bins=9, action_dim=5,
                         context_length=6, reward_values=[0.0, 1.0])  # fmt: skip
    torch.manual_seed(0)
    model = ICRLModel(config).eval()
    B, T = 2, 6
    batch = labelled_dicp_batch(B, T, same_next_states=True)
    states, rewards = batch["states"], batch["reward_labels"]
    out = model(**batch)
    assert out.reward_logits.shape == (B, T, 2)
    assert torch.equal(out.reward_pred, out.reward_logits.argmax(-1).float())
    ce = F.cross_entropy(out.reward_logits.flatten(0, 1), rewards.long().flatten())
    state_ce = F.cross_entropy(out.next_state_logits.flatten(0, 2), states.flatten())
    ret = F.mse_loss(out.return_pred, rewards / config.return_scale)
    torch.testing.assert_close(out.dynamics_loss, ce + state_ce + ret)
    with pytest.raises(ValueError, match="reward 0.5 is not one of the model's reward values"):
        model(**{**batch, "reward_labels": rewards + 0.5})
    model.save_pretrained(tmp_path)
    again = AutoModel.from_pretrained(tmp_path).eval()
    assert again.config.reward_values == [0.0, 1.0]
    torch.testing.assert_close(again(**batch).reward_logits, out.reward_logits)
    with pytest.raises(ValueError, match="reward_values"):
        icrl_config("tiny", objective="dicp", reward_values=[1.0, 0.0])


def test_cell_encoding_features_next_state_class_and_round_trip(tmp_path):
    """``state_encoding="cells"``: a state is the one-hot of its row-major cell (x * bins + y, by
    hand), the next-state head is one class over the cells (cross-entropy by hand), its argmax is
    decoded to coordinates, and the config survives save/load."""
    import torch.nn.functional as F

    config = icrl_config("tiny", objective="dicp", state_dim=2, state_bins=9, action_dim=5,
                         context_length=6, reward_values=[0.0, 1.0], state_encoding="cells")  # fmt: skip
    torch.manual_seed(0)
    model = ICRLModel(config).eval()
    assert model.state_features == 81 and model.next_state_head.out_features == 81
    grid = torch.tensor([[x, y] for x in range(9) for y in range(9)])  # (81, 2) row-major
    assert torch.equal(model.encode_states(grid), torch.eye(81))
    assert torch.equal(model.cell_of(torch.tensor([[3, 7], [-2, 11]])), torch.tensor([34, 8]))
    assert torch.equal(model.coords_of(model.cell_of(grid)), grid)
    B, T = 2, 6
    batch = labelled_dicp_batch(B, T, same_next_states=False)
    nxt, rewards = batch["next_state_labels"], batch["reward_labels"]
    out = model(**batch)
    assert out.next_state_logits.shape == (B, T, 81)
    ce = F.cross_entropy(out.reward_logits.flatten(0, 1), rewards.long().flatten())
    cell = nxt[..., 0] * 9 + nxt[..., 1]  # (B, T)
    state_ce = F.cross_entropy(out.next_state_logits.flatten(0, 1), cell.flatten())
    ret = F.mse_loss(out.return_pred, rewards / config.return_scale)
    torch.testing.assert_close(out.dynamics_loss, ce + state_ce + ret)
    best = out.next_state_logits.argmax(-1)  # (B, T)
    pred = model.predicted_next_states({"next_state_logits": out.next_state_logits})
    assert torch.equal(pred, torch.stack([best // 9, best % 9], -1))
    model.save_pretrained(tmp_path)
    again = AutoModel.from_pretrained(tmp_path).eval()
    assert again.config.state_encoding == "cells"
    torch.testing.assert_close(again(**batch).next_state_logits, out.next_state_logits)


def test_cell_encoding_refuses_unknown_names_and_huge_grids():
    with pytest.raises(ValueError, match="ICRLConfig.state_encoding must be one of"):
        icrl_config("tiny", state_bins=9, state_encoding="pixels")
    with pytest.raises(ValueError, match="'cells' needs state_bins \\*\\* state_dim <= 4096"):
        icrl_config("tiny", state_dim=3, state_bins=17, state_encoding="cells")
    # real-valued states ignore the encoding
    assert not icrl_config("tiny", state_bins=0, state_encoding="cells").cell_encoded


def test_reward_weighting_actions_weights_by_hand_and_weighted_loss():
    """``reward_weighting="actions"``: within each class of the previous step's reward (and the
    group of first steps) a position weighs 1 / (A p(a | group)), checked on a hand-made batch; the
    reward loss is the weighted mean of the per-position cross-entropies; ``data`` is unweighted."""
    import torch.nn.functional as F

    config = icrl_config("tiny", objective="dicp", state_dim=2, state_bins=9, action_dim=5,
                         context_length=8, reward_values=[0.0, 1.0],
                         reward_weighting="actions")  # fmt: skip
    torch.manual_seed(0)
    model = ICRLModel(config).eval()
    B, T = 1, 8
    batch = labelled_dicp_batch(B, T, same_next_states=True)
    # previous reward 1 at positions 0-3 (actions 4, 4, 4, 0); previous reward 0 at 4-6 (actions
    # 1, 2, 1); position 7 is a history's first step (action 3)
    batch["prev_rewards"] = torch.tensor([[1.0, 1, 1, 1, 0, 0, 0, 0]])
    batch["has_prev"] = torch.tensor([[True] * 7 + [False]])
    batch["actions"] = torch.tensor([[4, 4, 4, 0, 1, 2, 1, 3]])
    mask = torch.ones(B, T, dtype=torch.bool)
    w = model.reward_weights(batch["actions"], batch["prev_rewards"], batch["has_prev"], mask)
    A = 5
    expected = torch.tensor([1 / (A * 3 / 4)] * 3 + [1 / (A * 1 / 4)]  # reward-1 group
                            + [1 / (A * 2 / 3), 1 / (A * 1 / 3), 1 / (A * 2 / 3)]  # reward-0 group
                            + [1 / (A * 1)])  # first steps  # fmt: skip
    torch.testing.assert_close(w, expected)
    # a group's weights sum to its size x the fraction of the actions it holds
    torch.testing.assert_close(w[:4].sum(), torch.tensor(4 * 2 / 5))
    out = model(**batch)
    ce = F.cross_entropy(out.reward_logits[0], batch["reward_labels"][0].long(), reduction="none")
    state_ce = F.cross_entropy(out.next_state_logits.flatten(0, 2), batch["states"].flatten())
    ret = F.mse_loss(out.return_pred, batch["reward_labels"] / config.return_scale)
    torch.testing.assert_close(out.dynamics_loss, (ce * w).sum() / w.sum() + state_ce + ret)
    # unweighted: the plain mean, as before the field existed
    model.config.reward_weighting = "data"
    out = model(**batch)
    torch.testing.assert_close(out.dynamics_loss, ce.mean() + state_ce + ret)


@pytest.mark.parametrize(
    "fields",
    [
        dict(objective="ad", reward_values=[0.0, 1.0]),  # no reward head
        dict(objective="dicp"),  # a regression head: no classes to group by
        dict(objective="dicp", reward_values=[0.0, 1.0], discrete_actions=False, state_bins=0),
    ],
)
def test_reward_weighting_actions_refused_where_it_does_not_apply(fields):
    with pytest.raises(ValueError, match="ICRLConfig.reward_weighting 'actions' is for DICP"):
        icrl_config("tiny", state_dim=2, action_dim=5, reward_weighting="actions",
                    **{"state_bins": 9, **fields})  # fmt: skip
    with pytest.raises(ValueError, match="reward_weighting must be one of"):
        icrl_config("tiny", reward_weighting="uniform")
