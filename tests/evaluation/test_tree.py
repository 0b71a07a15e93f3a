"""The planner's two tree engines compute one function: the kernel engine (``KernelTree``, the C++
tree attention) gives the torch reference's (``TorchTree``, ``LlamaModel.forward`` with the tree
mask) hidden states depth after depth, and ``beam_search`` / ``greedy_search`` choose the same
actions with the same scores and imagine the same rewards and states; on Darkroom (context 80) and
Darkroom-Permuted (context 200), window and cache contexts, with grouped-query attention.  The
engine choice falls back, or refuses, with the reason."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lhf_hf.configs import TrainConfig
from lhf_hf.envs import get_spec
from lhf_hf.errors import UserError
from lhf_hf.evaluation import Context, beam_search, greedy_search
from lhf_hf.evaluation.tree import KernelTree, TorchTree, kernel_unsupported, resolve_engine
from lhf_hf.modeling import ICRLModel, tree_attention
from lhf_hf.training import model_config_for

NO_KERNEL = tree_attention.available()
needs_kernel = pytest.mark.skipif(NO_KERNEL is not None, reason=f"no kernel: {NO_KERNEL}")


def _model(env="darkroom", preset="tiny", context=None, kv_heads=None, layers=None, seed=1):
    """A DICP model for ``env``; its dynamics heads sharpened so that candidates differ."""
    cfg = model_config_for(
        get_spec(env),
        TrainConfig(dataset="-", objective="dicp", out="-", preset=preset, context_length=context),
        True,
    )
    if kv_heads is not None:
        cfg.num_key_value_heads = kv_heads
    if layers is not None:
        cfg.num_hidden_layers = layers
    torch.manual_seed(seed)
    model = ICRLModel(cfg).eval()
    with torch.no_grad():
        model.reward_head.weight.mul_(20)
        model.next_state_head.weight.mul_(20)
    return model


def _context(model, mode, B, steps, seed=0):
    g = torch.Generator().manual_seed(seed)
    ctx = Context(model, mode=mode)
    D = model.config.hidden_size
    ctx.append(torch.randn(B, 1, D, generator=g))
    for _ in range(steps):
        ctx.append(torch.randn(B, 2, D, generator=g), [True, False])
    return ctx


@needs_kernel
@pytest.mark.parametrize("mode", ["window", "cache"])
@pytest.mark.parametrize("kv_heads, context", [(None, 6), (1, 6), (None, 2)])
def test_the_kernel_tree_equals_the_torch_tree_depth_after_depth(mode, kv_heads, context):
    """Three layers, a context past its window (the oldest tokens drop out as paths grow; with
    context 2 the deepest tokens see none of it), the groups and selections of a beam search
    (depth 0: query tokens only; then a transition token each query token sees)."""
    model = _model(context=context, layers=3, kv_heads=kv_heads)
    B, A, D = 3, 5, model.config.hidden_size
    ctx = _context(model, mode, B, steps=9)
    trees = [TorchTree(model, ctx), KernelTree(model, ctx, beams=4, group=1 + A, path=5)]
    g = torch.Generator().manual_seed(3)
    nb = 1
    for depth in range(4):
        shared = int(depth > 0)
        per_beam = A + shared
        offsets = torch.full((per_beam,), 2 * depth)
        is_query = torch.ones(per_beam, dtype=torch.bool)
        if shared:
            offsets[0], is_query[0] = 2 * depth - 1, False
        embeds = torch.randn(B, nb * per_beam, D, generator=g)
        want, got = (t.forward(embeds, offsets, is_query, shared) for t in trees)
        torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-5, msg=f"depth {depth}")
        keep = min(4, nb * A)
        parent = torch.randint(0, nb, (B, keep), generator=g)
        token = shared + torch.randint(0, A, (B, keep), generator=g)
        for t in trees:
            t.select(parent, token)
        nb = keep


def _searches(model, ctx, B, engine, horizon, g):
    c = model.config
    states = torch.randint(0, c.state_bins, (B, c.state_dim), generator=g)
    logits = torch.randn(B, c.action_dim, generator=g)
    trace: list = []
    action, score = beam_search(model, ctx, states, logits, horizon, c.plan_beams, engine=engine,
                                trace=trace)  # fmt: skip
    return action, score, trace


@needs_kernel
@pytest.mark.slow
@pytest.mark.parametrize(
    "env, context, mode, kv_heads",
    [("darkroom", 80, "window", None), ("darkroom", 80, "cache", 2),
     ("darkroom-permuted", 200, "window", None), ("darkroom-permuted", 200, "cache", 2)],
)  # fmt: skip
def test_beam_search_chooses_the_same_with_either_engine(env, context, mode, kv_heads):
    """Paper-size models (4 layers, 4 heads, head dim 8; GQA with 2 key heads) at the env's
    context and plan depth (8 on Darkroom, 16 on Darkroom-Permuted), 6 tasks: the same first
    actions, scores within float tolerance, and every depth's imagined rewards and next states
    identical."""
    model = _model(env, preset="paper", context=context, kv_heads=kv_heads)
    B = 6
    ctx = _context(model, mode, B, steps=context + 3)
    horizon = model.config.plan_horizon
    runs = {e: _searches(model, ctx, B, e, horizon, torch.Generator().manual_seed(5))
            for e in ("torch", "kernel")}  # fmt: skip
    (a_t, s_t, tr_t), (a_k, s_k, tr_k) = runs["torch"], runs["kernel"]
    assert torch.equal(a_t, a_k)
    torch.testing.assert_close(s_k, s_t, rtol=0, atol=1e-4)
    assert len(tr_t) == len(tr_k) == horizon
    for d_t, d_k in zip(tr_t, tr_k, strict=True):
        for key in ("states", "actions", "reward", "next_state"):
            np.testing.assert_array_equal(d_k[key], d_t[key], err_msg=f"depth {d_t['depth']} {key}")
    assert len({float(r) for d in tr_t for r in d["reward"].ravel()}) > 1  # rewards differ


@needs_kernel
def test_greedy_search_chooses_the_same_with_either_engine():
    """Continuous actions (a Meta-World model): the policy mean and samples, scored by the predicted
    reward (a regression head); both engines give the same rewards to float tolerance and pick
    the same candidate."""
    model = _model("metaworld-reach-wall", context=6, layers=2)
    B, c = 4, model.config
    ctx = _context(model, "cache", B, steps=8)
    g = torch.Generator().manual_seed(0)
    mean, log_std = torch.randn(B, c.action_dim, generator=g), torch.zeros(B, c.action_dim)
    states = torch.randn(B, c.state_dim, generator=g)
    picks = [
        greedy_search(model, ctx, states, mean, log_std, 16, np.random.default_rng(0), engine=e)
        for e in ("torch", "kernel")
    ]
    assert torch.equal(picks[0], picks[1])


def test_the_engine_falls_back_or_refuses_with_the_reason(monkeypatch):
    model = _model()
    if NO_KERNEL is None:
        assert resolve_engine(model, "auto") == "kernel"
        assert resolve_engine(model, "kernel") == "kernel"
    assert resolve_engine(model, "torch") == "torch"
    double = _model().double()
    assert "float32" in kernel_unsupported(double)
    assert resolve_engine(double, "auto") == "torch"
    with pytest.raises(UserError, match="kernel engine cannot run this model: dtype torch.float64"):
        resolve_engine(double, "kernel")
    with pytest.raises(UserError, match="unknown planner engine 'fast'"):
        resolve_engine(model, "fast")
    # a head dimension the kernel has no code for: the torch engine plans
    wide = _model()
    monkeypatch.setattr(wide.backbone.config, "head_dim", 4, raising=False)
    assert "head dims (8, 16), this model 4" in kernel_unsupported(wide)
    assert resolve_engine(wide, "auto") == "torch"
    ctx = _context(model, "cache", 1, steps=5)
    with pytest.raises(UserError, match="unknown planner engine"):
        beam_search(model, ctx, torch.zeros(1, 2, dtype=torch.long), torch.zeros(1, 5), 2, 10,
                    engine="fast")  # fmt: skip
