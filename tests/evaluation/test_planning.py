"""DICP planners against a stand-in model whose dynamics and rewards are known exactly."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lhf_hf.evaluation import Context, beam_search, greedy_search

LEFT, RIGHT, STAY = 0, 1, 2


class ChainModel:
    """A stand-in for ICRLModel on a chain of 10 cells with 3 actions.

    Token "embeddings" carry (state, action) in plain numbers and the backbone is the identity, so
    the dynamics heads read the exact (s, a) of each query-action token: next state = s -/+ 1 (or s),
    reward = ``reward(s, a)``.  The policy prefers the actions in ``policy_order``.
    """

    def __init__(self, reward, policy_order=(STAY, RIGHT, LEFT)):
        self.reward = reward
        self.policy_logits = torch.zeros(3)
        for rank, a in enumerate(policy_order):
            self.policy_logits[a] = -rank
        self.config = type("C", (), {"objective": "dicp", "context_length": 4})()

    @staticmethod
    def step(s, a):
        return torch.clamp(s + torch.where(a == LEFT, -1, torch.where(a == RIGHT, 1, 0)), 0, 9)

    def embed_query_actions(self, states, actions):  # (N, 1, S), (N, 1) -> (N, 1, 3)
        return torch.stack(
            [states[..., 0].float(), actions.float(), torch.ones_like(actions, dtype=torch.float)],
            -1,
        )

    def embed_transitions(
        self, states, prev_states, prev_actions, prev_rewards, prev_dones, has_prev
    ):
        return torch.stack(
            [
                states[..., 0].float(),
                torch.full_like(states[..., 0], -1).float(),
                torch.zeros_like(states[..., 0]).float(),
            ],
            -1,
        )

    def run_backbone(
        self,
        inputs_embeds,
        backbone_cache=None,
        position_ids=None,
        use_cache=None,
        attention_mask=None,
    ):
        return inputs_embeds, backbone_cache

    def action_distribution(self, hidden):
        return {"action_logits": self.policy_logits.expand(*hidden.shape[:-1], 3)}

    def dynamics(self, hidden):
        s, a = hidden[..., 0].long(), hidden[..., 1].long()
        nxt = self.step(s, a)
        r = torch.tensor(
            [
                [self.reward(int(x), int(y)) for x, y in zip(row_s, row_a, strict=True)]
                for row_s, row_a in zip(s, a, strict=True)
            ]
        )
        return {
            "reward_pred": r.float(),
            "next_state_logits": torch.nn.functional.one_hot(nxt, 10).unsqueeze(-2).float(),
            "return_pred": torch.zeros_like(r).float(),
        }

    @staticmethod
    def predicted_next_states(out):
        return out["next_state_logits"].argmax(-1)


def goal_reward(s, a):
    """1 for every step that ends on cell 8; a bait of 0.45 for stepping left from cell 5."""
    nxt = int(ChainModel.step(torch.tensor(s), torch.tensor(a)))
    return (1.0 if nxt == 8 else 0.0) + (0.45 if (s, a) == (5, LEFT) else 0.0)


def plan(model, start: int, horizon: int, beams: int = 10) -> int:
    ctx = Context(model, mode="cache", max_tokens=8)
    states = torch.tensor([[start]])
    ctx.append(model.embed_transitions(states[:, None], None, None, None, None, None))
    logits = model.policy_logits[None]
    return int(beam_search(model, ctx, states, logits, horizon, beams)[0][0])


def test_beam_search_finds_the_best_plan_not_the_greedy_step():
    model = ChainModel(goal_reward)
    # horizon 4 from cell 5: right, right, right (1), stay (1) = 2 > left, right, left, . = 0.9
    assert plan(model, 5, horizon=4) == RIGHT
    # horizon 1: only the bait pays
    assert plan(model, 5, horizon=1) == LEFT
    # horizon 3 reaches cell 8 at the last step: 1 > the bait taken twice (left, right, left) = 0.9
    assert plan(model, 5, horizon=3) == RIGHT
    # horizon 2 cannot reach cell 8: the bait wins
    assert plan(model, 5, horizon=2) == LEFT


def test_beam_search_breaks_ties_by_the_policy_order():
    no_reward = ChainModel(lambda s, a: 0.0, policy_order=(RIGHT, STAY, LEFT))
    assert plan(no_reward, 5, horizon=3) == RIGHT
    no_reward = ChainModel(lambda s, a: 0.0, policy_order=(LEFT, RIGHT, STAY))
    assert plan(no_reward, 5, horizon=3) == LEFT


def test_beam_search_batches_independent_streams():
    model = ChainModel(goal_reward)
    ctx = Context(model, mode="cache", max_tokens=8)
    states = torch.tensor([[5], [7], [9]])
    ctx.append(model.embed_transitions(states[:, None], None, None, None, None, None))
    logits = model.policy_logits.expand(3, 3)
    got = beam_search(model, ctx, states, logits, horizon=4, beams=10)[0].tolist()
    # from 7 step right onto 8; from 9 step left onto 8
    assert got == [RIGHT, RIGHT, LEFT]


def test_a_narrow_beam_can_miss_the_best_plan():
    """With one beam the search keeps only the best partial path (the bait) and cannot recover."""
    model = ChainModel(goal_reward)
    assert plan(model, 5, horizon=4, beams=1) == LEFT


class BanditModel:
    """Continuous stand-in: the predicted reward is -(a - 0.3)^2 summed over the action dims."""

    config = type("C", (), {"objective": "dicp", "context_length": 4})()

    def embed_query_actions(self, states, actions):
        return actions.float()

    def run_backbone(
        self,
        inputs_embeds,
        backbone_cache=None,
        position_ids=None,
        use_cache=None,
        attention_mask=None,
    ):
        return inputs_embeds, backbone_cache

    def dynamics(self, hidden):
        return {"reward_pred": -((hidden - 0.3) ** 2).sum(-1)}


def test_greedy_search_picks_the_candidate_with_the_highest_predicted_reward():
    model = BanditModel()
    ctx = Context(model, mode="cache", max_tokens=4)
    ctx.append(torch.zeros(2, 1, 2))
    mean = torch.tensor([[0.0, 0.0], [0.3, 0.3]])
    log_std = torch.zeros(2, 2)
    rng = np.random.default_rng(0)
    best = greedy_search(model, ctx, torch.zeros(2, 1), mean, log_std, samples=200, rng=rng)
    # stream 0: some sample lands near 0.3 and beats the mean (0, 0); stream 1: the mean is optimal
    assert torch.all((best[0] - 0.3).abs() < 0.15) and not torch.allclose(best[0], mean[0])
    torch.testing.assert_close(best[1], mean[1])


# ---------------------------------------------------------------------------- a real model
@torch.no_grad()
def naive_beam_search(
    model, window, state, logits, horizon, beams, max_tokens, encode=None, ties="index"
):
    """Reference: every candidate re-runs the backbone over its own linear token sequence (the
    context window + its path, cut to the training window, as the reference code does per beam; or
    ``encode(tokens, last_is_query)``).  Ties below depth 0: ``index`` lays candidates out beam by
    beam, actions by index, and sorts stably (jaehyeon-son/dicp ``ad.py``); ``policy`` ranks each
    beam's actions by its policy, interleaved over beams."""
    A = logits.shape[-1]

    def last_hidden(tokens, window_len):
        seq = torch.cat(tokens, dim=1)[:, -window_len:]  # (1, L, D)
        pos = torch.arange(seq.shape[1])[None]
        return model.run_backbone(seq, position_ids=pos, use_cache=False)[0][:, -1:]

    if encode is None:

        def encode(tokens, query):
            return last_hidden(tokens, max_tokens + int(query))

    beams_ = [dict(path=[], state=state, score=0.0, first=None, policy=logits)]
    for depth in range(horizon):
        cands = []
        for bi, beam in enumerate(beams_):
            rank = torch.argsort(torch.argsort(-beam["policy"], stable=True))
            for a in range(A):
                q = model.embed_query_actions(beam["state"][None, None], torch.tensor([[a]]))
                h = encode([window, *beam["path"], q], True)
                dyn = model.dynamics(h)
                r = float(dyn["reward_pred"][0, 0])
                nxt = model.predicted_next_states(dyn)[0, 0]
                cands.append(
                    dict(
                        score=beam["score"] + r,
                        key=bi * A + a
                        if depth > 0 and ties == "index"
                        else int(rank[a]) * len(beams_) + bi,
                        beam=beam,
                        a=a,
                        r=r,
                        nxt=nxt,
                        q=q,
                        first=a if beam["first"] is None else beam["first"],
                    )
                )
        cands.sort(key=lambda c: c["key"])
        cands.sort(key=lambda c: -c["score"])
        cands = cands[:beams]
        if depth == horizon - 1:
            return cands[0]["first"], cands[0]["score"]
        beams_ = []
        for c in cands:
            t = model.embed_transitions(
                states=c["nxt"][None, None],
                prev_states=c["beam"]["state"][None, None],
                prev_actions=torch.tensor([[c["a"]]]),
                prev_rewards=torch.tensor([[c["r"]]]),
                prev_dones=torch.tensor([[False]]),
                has_prev=torch.tensor([[True]]),
            )
            path = [*c["beam"]["path"], c["q"], t]
            policy = model.action_distribution(encode([window, *path], False))["action_logits"][
                0, 0
            ]
            beams_.append(
                dict(path=path, state=c["nxt"], score=c["score"], first=c["first"], policy=policy)
            )


def _dicp_model(layers, context):
    from lhf_hf.configs import TrainConfig
    from lhf_hf.envs import get_spec
    from lhf_hf.modeling import ICRLModel
    from lhf_hf.training import model_config_for

    cfg = model_config_for(
        get_spec("darkroom"),
        TrainConfig(dataset="-", objective="dicp", out="-", preset="tiny", context_length=context),
        True,
    )
    cfg.num_hidden_layers = layers
    torch.manual_seed(1)
    model = ICRLModel(cfg).eval()
    # sharpen the dynamics heads so that rewards and imagined states differ between candidates
    with torch.no_grad():
        model.reward_head.weight.mul_(20)
        model.next_state_head.weight.mul_(20)
    return model


@pytest.mark.slow
@pytest.mark.parametrize("ties", ["index", "policy"])
@pytest.mark.parametrize("layers, context, steps", [(1, 4, 12), (2, 12, 6)])
def test_tree_beam_search_equals_per_candidate_recompute(layers, context, steps, ties):
    """The shared-context tree (one backbone call per depth) gives the per-candidate recompute's
    choice and score.  One layer with a full window (the oldest context tokens drop out as paths
    grow); two layers while the window is not yet full (keys of deeper layers are not recomputed)."""
    model = _dicp_model(layers, context)
    g = torch.Generator().manual_seed(0)
    ctx = Context(model, mode="window")
    for _ in range(steps):  # a context of random tokens (2 per transition for DICP)
        ctx.append(torch.randn(1, 2, model.config.hidden_size, generator=g))
    state = torch.tensor([[4, 4]])
    logits = torch.randn(1, 5, generator=g)
    for horizon, beams in [(1, 10), (3, 10), (4, 2)]:
        want_a, want_score = naive_beam_search(
            model, ctx.embeds, state[0], logits[0], horizon, beams, ctx.max_tokens, ties=ties
        )
        got_a, got_score = beam_search(model, ctx, state, logits, horizon, beams, ties=ties)
        assert int(got_a[0]) == want_a, (horizon, beams)
        assert abs(float(got_score[0]) - want_score) < 1e-4, (
            horizon,
            beams,
            float(got_score[0]),
            want_score,
        )


@pytest.mark.slow
def test_tree_beam_search_on_the_cache_is_exact_at_depth():
    """The rollout's default: the KV cache after many evictions, three layers.  Every candidate's
    reward and the policy at every imagined state must equal one forward over the whole stream (the
    context's tokens and the candidate's path) with the sliding-window band, the context's
    definition (``lhf_hf.evaluation.context``): identical choice and score."""
    from lhf_hf.modeling.attention import band_mask

    model = _dicp_model(3, 4)
    D = model.config.hidden_size
    g = torch.Generator().manual_seed(2)
    ctx = Context(model, mode="cache")
    W = ctx.max_tokens
    first = torch.randn(1, 1, D, generator=g)
    ctx.append(first)
    stream, wins = [first], [W]
    for _ in range(12):  # Q, T per step as in a rollout: the window of 4 transitions slides
        tok = torch.randn(1, 2, D, generator=g)
        ctx.append(tok, [True, False])
        stream.append(tok)
        wins += [W + 1, W]
    seq = torch.cat(stream, dim=1)  # (1, 25, D)

    def encode(tokens, query):
        path = len(tokens) - 1  # imagined tokens: Q, T, Q, T, ...
        full = torch.cat(tokens, dim=1)  # (1, N, D)
        w = torch.tensor(wins + [W + 1 if i % 2 == 0 else W for i in range(path)])
        pos = torch.arange(full.shape[1])
        bias = band_mask(pos, w, pos)[None, None]
        return model.run_backbone(
            full, position_ids=pos[None], use_cache=False, attention_mask=bias
        )[0][:, -1:]

    state = torch.tensor([[4, 4]])
    logits = torch.randn(1, 5, generator=g)
    for horizon, beams in [(1, 10), (3, 10), (4, 2)]:
        want_a, want_score = naive_beam_search(
            model, seq, state[0], logits[0], horizon, beams, W, encode=encode
        )
        got_a, got_score = beam_search(model, ctx, state, logits, horizon, beams)
        assert int(got_a[0]) == want_a, (horizon, beams)
        assert abs(float(got_score[0]) - want_score) < 1e-4, (horizon, beams)


@pytest.mark.slow
def test_the_planner_with_true_dynamics_is_near_optimal():
    """Oracle dynamics (the env's own reward and next state inside the beam search, the policy of
    an untrained DICP model ordering ties): the planner's machinery alone must walk straight to
    every goal its beams can see.  With 10 beams and 5 actions the search is exhaustive to depth 2
    (25 paths), so goals within 2 steps of the start are found from the first planned step; farther
    ones need a policy that points the beams their way (the reference's beam search, too)."""
    from lhf_hf.envs import get_spec
    from lhf_hf.evaluation.rollout import rollout
    from lhf_hf.evaluation.task_batch import make_task_batch

    model = _dicp_model(1, 4)
    tasks = [40, 31, 41, 50, 22, 38]  # the start cell (4, 4), its neighbours, 2 steps away
    batch = make_task_batch("darkroom", tasks, 0, 0)
    res = rollout(model, batch, 4, seed=0, plan=True, progress=False, plan_dynamics="oracle")
    optimal = get_spec("darkroom").optimal_returns()[tasks]
    late = res.returns[:, 1:]  # (tasks, episodes): planning from the second episode on
    np.testing.assert_allclose(late, np.repeat(optimal[:, None], late.shape[1], 1))
    # the learned heads of the same (untrained) model are far from it
    learned = rollout(model, make_task_batch("darkroom", tasks, 0, 0), 4, seed=0, plan=True,
                      progress=False).returns[:, 1:]  # fmt: skip
    assert learned.mean() < 0.5 * optimal.mean()
    with pytest.raises(ValueError, match="without a key"):
        rollout(model, make_task_batch("dark-key-to-door", [0], 0, 0), 2, plan=True,
                progress=False, plan_dynamics="oracle")  # fmt: skip


@pytest.mark.slow
def test_tied_rewards_make_the_planned_action_a_policy_sample():
    """Reward classes predicting 0 everywhere (all paths tie): with the sampled depth-0 order (the
    reference's) the first action is a draw from the policy, by frequency; with ``argmax`` it is
    always the policy's mode."""
    from lhf_hf.configs import TrainConfig
    from lhf_hf.envs import get_spec
    from lhf_hf.modeling import ICRLModel
    from lhf_hf.training import model_config_for

    cfg = model_config_for(get_spec("darkroom"), TrainConfig(dataset="-", objective="dicp",
                           out="-", preset="tiny", context_length=4), True)  # fmt: skip
    assert cfg.reward_values == [0.0, 1.0]  # the gridworlds' reward classes
    torch.manual_seed(0)
    model = ICRLModel(cfg).eval()
    with torch.no_grad():  # class 0 (reward 0) always wins: every path scores 0
        model.reward_head.weight.zero_()
        model.reward_head.bias.copy_(torch.tensor([1.0, -1.0]))
    ctx = Context(model, mode="cache")
    g = torch.Generator().manual_seed(0)
    for _ in range(4):
        ctx.append(torch.randn(1, 2, cfg.hidden_size, generator=g))
    logits = torch.tensor([[0.0, 1.0, 2.0, 0.5, -1.0]])
    state = torch.tensor([[4, 4]])
    gen = torch.Generator().manual_seed(3)
    n = 3000
    counts = np.bincount(
        [
            int(beam_search(model, ctx, state, logits, 2, 10, order="sample", generator=gen)[0][0])
            for _ in range(n)
        ],  # fmt: skip
        minlength=5,
    )
    p = torch.softmax(logits[0], 0).numpy()
    assert np.all(np.abs(counts / n - p) < 4 * np.sqrt(p * (1 - p) / n) + 1e-3), (counts / n, p)
    assert all(int(beam_search(model, ctx, state, logits, 2, 10)[0][0]) == 2 for _ in range(5))
    with pytest.raises(ValueError, match="order must be"):
        beam_search(model, ctx, state, logits, 1, 10, order="random")
    # the trace holds every candidate the planner imagined, depth by depth
    trace: list = []
    beam_search(model, ctx, state, logits, 3, 10, trace=trace)
    assert [d["depth"] for d in trace] == [0, 1, 2]
    assert [d["actions"].shape for d in trace] == [(1, 5), (1, 25), (1, 50)]
    assert trace[0]["states"].shape == (1, 5, 2) and (trace[0]["states"] == [4, 4]).all()
    assert all((d["reward"] == 0).all() for d in trace)  # class 0 everywhere


def test_ties_below_depth_0_follow_the_reference_layout_or_the_policy():
    """No reward anywhere, 10 beams of 5 actions: with the reference's ties (``index``: beam by
    beam, actions by index, stable sort; jaehyeon-son/dicp ``ad.py``) depth 1 keeps the children
    of the two best first actions and from depth 2 on every kept path starts with the best one;
    with ``ties="policy"`` every first action stays in the tree.  Dynamics that write a path's
    first action into its state show which paths were kept."""
    from lhf_hf.configs import TrainConfig
    from lhf_hf.envs import get_spec
    from lhf_hf.modeling import ICRLModel
    from lhf_hf.training import model_config_for

    cfg = model_config_for(get_spec("darkroom"), TrainConfig(dataset="-", objective="dicp",
                           out="-", preset="tiny", context_length=4), True)  # fmt: skip
    torch.manual_seed(0)
    model = ICRLModel(cfg).eval()
    ctx = Context(model, mode="cache")
    g = torch.Generator().manual_seed(0)
    for _ in range(4):
        ctx.append(torch.randn(1, 2, cfg.hidden_size, generator=g))

    def first_action_dynamics(states, actions):  # (B, N, 2), (B, N): (depth, first action)
        nxt = states.copy()
        start = states[..., 0] == 0
        nxt[..., 0] = np.minimum(states[..., 0] + 1, 8)
        nxt[..., 1] = np.where(start, actions, states[..., 1])
        return nxt, np.zeros(actions.shape, dtype=np.float32)

    logits = torch.tensor([[0.0, 1.0, 2.0, 0.5, -1.0]])  # argmax order: 2, 1, 3, 0, 4
    kept = {}
    for ties in ("index", "policy"):
        trace: list = []
        a, score = beam_search(model, ctx, torch.tensor([[0, 0]]), logits, 4, 10,
                               dynamics=first_action_dynamics, ties=ties, trace=trace)  # fmt: skip
        assert int(a[0]) == 2 and float(score[0]) == 0.0
        # the first actions of the paths each depth extends (its candidates' from-states)
        kept[ties] = [set(d["states"][0, :, 1].tolist()) for d in trace[1:]]  # depth 1, 2, 3
    assert kept["index"] == [set(range(5)), {2, 1}, {2}]  # the two best, then the best only
    assert kept["policy"] == [set(range(5))] * 3
    with pytest.raises(ValueError, match="ties must be"):
        beam_search(model, ctx, torch.tensor([[0, 0]]), logits, 2, 10, ties="random")


def test_a_reward_threshold_imagines_only_confident_rewards():
    """Reward classes [0, 1]: the reference imagines the most likely class; with a threshold a
    reward of 1 only where its probability reaches it (hand-computed softmax)."""
    from lhf_hf.evaluation.planning import imagined_reward

    model = _dicp_model(1, 4)
    assert model.config.reward_values == [0.0, 1.0]
    # logit gaps 0, ln 3 and ln 19: p(reward 1) = 0.5, 0.75, 0.95
    gap = torch.tensor([[-1.0, 0.0, np.log(3), np.log(19)]])  # (B 1, N 4)
    logits = torch.stack([torch.zeros_like(gap), gap], -1)  # (1, 4, 2)
    dyn = {"reward_logits": logits, "reward_pred": torch.tensor([[0.0, 0.0, 1.0, 1.0]])}
    assert imagined_reward(model, dyn).tolist() == [[0.0, 0.0, 1.0, 1.0]]  # argmax (ties: 0)
    assert imagined_reward(model, dyn, 0.7).tolist() == [[0.0, 0.0, 1.0, 1.0]]
    assert imagined_reward(model, dyn, 0.9).tolist() == [[0.0, 0.0, 0.0, 1.0]]
    assert imagined_reward(model, dyn, 0.96).tolist() == [[0.0, 0.0, 0.0, 0.0]]
    with pytest.raises(ValueError, match="reward classes that include 0"):
        imagined_reward(model, {"reward_pred": dyn["reward_pred"]}, 0.9)


@pytest.mark.slow
def test_a_threshold_above_the_phantom_s_probability_lets_the_policy_act():
    """A reward head that gives reward 1 a probability of 0.6 everywhere: the reference planner
    sees a reward on every path; above 0.6 the planner sees none, so (sampled order) it acts
    as the policy would; a threshold without planning, or outside (0, 1), is refused."""
    from lhf_hf.configs import EvalConfig
    from lhf_hf.evaluation.rollout import rollout
    from lhf_hf.evaluation.task_batch import make_task_batch

    model = _dicp_model(1, 4)
    with torch.no_grad():
        model.reward_head.weight.zero_()
        model.reward_head.bias.copy_(torch.tensor([0.0, float(np.log(1.5))]))  # p(1) = 0.6
    ctx = Context(model, mode="cache")
    g = torch.Generator().manual_seed(0)
    for _ in range(4):
        ctx.append(torch.randn(1, 2, model.config.hidden_size, generator=g))
    logits, state = torch.zeros(1, 5), torch.tensor([[4, 4]])
    _, score = beam_search(model, ctx, state, logits, 2, 10)
    assert float(score[0]) == 2.0  # a phantom reward at both depths
    _, score = beam_search(model, ctx, state, logits, 2, 10, reward_threshold=0.7)
    assert float(score[0]) == 0.0
    batch = make_task_batch("darkroom", [3], 0, 0)
    with pytest.raises(ValueError, match="pass plan=True"):
        EvalConfig(model="m", out="o", plan_reward_threshold=0.9)
    with pytest.raises(ValueError, match="the true dynamics .* have none"):
        EvalConfig(model="m", out="o", plan=True, plan_dynamics="oracle", plan_reward_threshold=0.9)
    for bad in (0.0, 1.0, 1.5):
        with pytest.raises(ValueError, match=r"a probability in \(0, 1\)"):
            EvalConfig(model="m", out="o", plan=True, plan_reward_threshold=bad)
    res = rollout(model, batch, 2, seed=0, plan=True, progress=False, plan_reward_threshold=0.7)
    assert res.returns.shape == (1, 2)
