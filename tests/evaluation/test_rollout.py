"""In-context rollouts: cache vs recompute, planning schedule, evaluate() outputs, compare(), errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from lhf_hf.cli.main import main
from lhf_hf.configs import EvalConfig, TrainConfig
from lhf_hf.envs import get_spec, task_split
from lhf_hf.evaluation import compare, evaluate, make_task_batch, rollout
from lhf_hf.evaluation.compare import backbone_of
from lhf_hf.modeling import ICRLModel, attention_kernel, tree_attention
from lhf_hf.training import model_config_for


def darkroom_model(objective="ad", layers=1, context=10, seed=0, split_seed=0):
    """A tiny untrained model that records, as ``lhf train`` would, the train goals of
    ``split_seed`` as its training tasks (so its test goals are unseen)."""
    cfg = model_config_for(
        get_spec("darkroom"),
        TrainConfig(
            dataset="-", objective=objective, out="-", preset="tiny", context_length=context
        ),
        True,
    )
    cfg.num_hidden_layers = layers
    cfg.train_tasks, cfg.split_seed = sorted(task_split("darkroom", split_seed)[0]), split_seed
    torch.manual_seed(seed)
    return ICRLModel(cfg).eval()


def actions(model, episodes, context, plan=False, seed=3):
    _, test = task_split("darkroom", 0)
    r = rollout(
        model,
        make_task_batch("darkroom", test, 0, 0),
        episodes,
        seed=seed,
        plan=plan,
        context=context,
        progress=False,
        record_actions=True,
    )
    return r


@pytest.mark.slow
@pytest.mark.parametrize("objective", ["ad", "dicp"])
def test_cache_and_recompute_take_identical_actions_paper_depth(objective):
    """Four layers (the paper's depth), 100 steps through a window of 10 transitions: the sliding KV
    cache and the recompute over the receptive field are the same function (identical actions and
    returns with the same random stream), evictions and DICP's two tokens per step included."""
    model = darkroom_model(objective, layers=4, context=10)
    a, b = actions(model, 5, "cache"), actions(model, 5, "recompute")
    np.testing.assert_array_equal(a.actions, b.actions)
    np.testing.assert_array_equal(a.returns, b.returns)


@pytest.mark.slow
@pytest.mark.parametrize("objective", ["ad", "dicp"])
def test_window_protocol_equals_the_cache_for_one_layer_and_until_the_window_fills(objective):
    one = darkroom_model(objective, layers=1, context=10)
    np.testing.assert_array_equal(
        actions(one, 4, "cache").actions, actions(one, 4, "window").actions
    )
    deep = darkroom_model(objective, layers=3, context=30)
    a, b = actions(deep, 2, "cache"), actions(deep, 2, "window")
    np.testing.assert_array_equal(a.actions[:, :30], b.actions[:, :30])


@pytest.mark.slow
def test_planning_starts_once_the_context_is_full():
    model = darkroom_model("dicp", layers=1, context=10)
    r = actions(model, 2, "cache", plan=True)
    assert r.planned_steps == 40 - 9  # steps 10..40 (the context holds 10 transitions from step 10)
    for mode in ("recompute", "window"):  # planning in every context mode agrees (one layer)
        np.testing.assert_array_equal(r.actions, actions(model, 2, mode, plan=True).actions)
    deep = darkroom_model("dicp", layers=3, context=6)
    a, b = actions(deep, 2, "cache", plan=True), actions(deep, 2, "recompute", plan=True)
    np.testing.assert_array_equal(a.actions, b.actions)  # exact at depth: the same function


@pytest.mark.slow
def test_reward_gate_plans_only_for_tasks_that_have_seen_a_reward():
    """``plan_gate="reward_seen"``: a task whose context never held a reward acts on the policy's
    own samples (the planner draws from its own generator, so such a task takes exactly the
    no-planning actions); without the gate the search steers those tasks too."""
    model = darkroom_model("dicp", layers=1, context=10)
    _, test = task_split("darkroom", 0)
    goals = list(test) * 2  # 16 rows: most of them never reach their goal in 2 episodes

    def run(**kw):
        batch = make_task_batch("darkroom", goals, 0, 0)
        return rollout(model, batch, 2, seed=5, progress=False, record_actions=True, **kw)

    free, gated, always = run(), run(plan=True, plan_gate="reward_seen"), run(plan=True)
    unrewarded = (gated.returns.sum(1) == 0) & (free.returns.sum(1) == 0)
    assert unrewarded.sum() >= 4
    np.testing.assert_array_equal(gated.actions[unrewarded], free.actions[unrewarded])
    assert not np.array_equal(always.actions[unrewarded], free.actions[unrewarded])
    # the search runs on the same steps; only tasks with a reward in the context act on it
    assert gated.planned_steps == always.planned_steps
    assert always.planned_actions == 16 * always.planned_steps
    assert gated.planned_actions <= (16 - unrewarded.sum()) * gated.planned_steps
    with pytest.raises(ValueError, match="plan_gate must be"):
        run(plan=True, plan_gate="sometimes")
    with pytest.raises(ValueError, match="plan_gate is a planning setting"):
        EvalConfig(model="m", out="o", plan_gate="reward_seen")


def test_same_seed_same_rollout_other_seed_differs():
    model = darkroom_model("ad")
    a, b, c = (
        actions(model, 2, "cache", seed=1),
        actions(model, 2, "cache", seed=1),
        actions(model, 2, "cache", seed=2),
    )
    np.testing.assert_array_equal(a.actions, b.actions)
    assert not np.array_equal(a.actions, c.actions)


@pytest.mark.slow
def test_evaluate_writes_results_curve_and_model_card(tmp_path):
    from lhf_hf.training.card import write_model_card

    model = darkroom_model("dicp", split_seed=3)
    model.save_pretrained(tmp_path / "m")
    prov = {
        "train": TrainConfig(dataset="d", objective="dicp", out="m").to_dict(),
        "dataset": {"path": "d", "env_id": "darkroom", "split_seed": 3, "fingerprint": "0" * 64},
        "selection": None,
    }
    (tmp_path / "m" / "train_config.json").write_text(json.dumps(prov))
    write_model_card(tmp_path / "m", model.config, prov)
    r = evaluate(
        EvalConfig(model=str(tmp_path / "m"), out=str(tmp_path / "ev"), episodes=3, plan=True),
        progress=False,
    )
    _, test = task_split("darkroom", 3)  # the training dataset's split by default
    assert r["split_seed"] == 3 and r["tasks"] == list(test) and len(r["tasks"]) == 8
    assert np.asarray(r["returns"]).shape == (8, 3) and r["planned_steps"] > 0
    # the default context is the model's training semantics: windows for a window-trained model
    assert r["context"] == "window" and r["config"]["context"] == "auto"
    assert r["engine"] == ("kernel" if attention_kernel.available() is None else "hf")
    assert r["plan_engine"] == ("kernel" if tree_attention.available() is None else "torch")
    assert np.isclose(r["mean_return"], np.mean(r["returns"]))
    saved = json.loads((tmp_path / "ev" / "eval_results.json").read_text())
    assert (
        saved["config"]["plan"]
        and saved["model"]["objective"] == "dicp"
        and "torch" in saved["versions"]
    )
    assert (tmp_path / "ev" / "eval_curve.png").stat().st_size > 0
    card = (tmp_path / "m" / "README.md").read_text()
    assert "model-index:" in card and "mean_reward" in card and "| darkroom | 8 test |" in card
    evaluate(
        EvalConfig(model=str(tmp_path / "m"), out=str(tmp_path / "ev4"), episodes=1, rollouts=4),
        progress=False,
    )
    gated = EvalConfig(
        model=str(tmp_path / "m"), out=str(tmp_path / "evg"), episodes=1, plan=True,
        plan_gate="reward_seen",
    )  # fmt: skip
    assert evaluate(gated, progress=False)["planned_actions"] >= 0
    card = (tmp_path / "m" / "README.md").read_text()
    flat = " ".join(card.split())  # the model-index YAML may fold long names
    assert (
        "| darkroom | 8 test x 4 | unseen tasks | 3 | 0 |" in card
        and "(seed 0, 4 rollouts per task, context window)" in flat
    )


def test_rollouts_roll_each_task_out_several_times_with_their_own_draws(tmp_path):
    """``rollouts=3``: every unseen goal three times in one batch (rollout-major rows), each copy
    with its own action draws; the curve and the per-rollout means average all of them."""
    model = darkroom_model("ad")
    _, test = task_split("darkroom", 0)
    r = rollout(
        model,
        make_task_batch("darkroom", list(test) * 2, 0, 0),
        2,
        seed=3,
        progress=False,
        record_actions=True,
    )
    assert r.actions.shape == (16, 2 * get_spec("darkroom").horizon)
    assert not np.array_equal(r.actions[:8], r.actions[8:])  # same goals, other draws
    model.save_pretrained(tmp_path / "m")
    out = evaluate(
        EvalConfig(model=str(tmp_path / "m"), out=str(tmp_path / "ev"), episodes=2, rollouts=3),
        progress=False,
    )
    returns = np.asarray(out["returns"])
    assert out["tasks"] == list(test) and out["rollouts"] == 3 and returns.shape == (24, 2)
    per_rollout = returns.reshape(3, 8, 2).mean((1, 2))
    np.testing.assert_allclose(out["rollout_mean_returns"], per_rollout)
    assert np.isclose(out["mean_return"], per_rollout.mean())
    for bad in (0, -2, 10**11):
        with pytest.raises(ValueError, match="rollouts must be between 1 and 1000"):
            EvalConfig(model="m", out="o", rollouts=bad)


def test_evaluate_errors(tmp_path):
    ad = darkroom_model("ad")
    ad.save_pretrained(tmp_path / "ad")
    with pytest.raises(ValueError, match="dynamics heads"):
        evaluate(
            EvalConfig(model=str(tmp_path / "ad"), out=str(tmp_path / "e"), episodes=1, plan=True)
        )
    with pytest.raises(ValueError, match="trained on 'darkroom'"):
        evaluate(
            EvalConfig(
                model=str(tmp_path / "ad"),
                out=str(tmp_path / "e"),
                env_id="darkroom-large",
                episodes=1,
            )
        )
    with pytest.raises(ValueError, match="discrete action head"):
        evaluate(
            EvalConfig(
                model=str(tmp_path / "ad"),
                out=str(tmp_path / "e"),
                env_id="metaworld-reach",
                episodes=1,
            )
        )
    with pytest.raises(FileNotFoundError, match="no model checkpoint"):
        evaluate(EvalConfig(model=str(tmp_path / "none"), out=str(tmp_path / "e")))
    with pytest.raises(ValueError, match="episodes"):
        EvalConfig(model="m", out="o", episodes=0)
    with pytest.raises(
        ValueError, match=r"context must be one of \('auto', 'cache', 'recompute', 'window'\)"
    ):
        EvalConfig(model="m", out="o", context="fast")


def fake_eval(path, objective, curve, env="darkroom", plan=False, split=0, tasks=(3, 5), context="cache", **settings):  # fmt: skip
    path.mkdir(parents=True)
    (path / "eval_results.json").write_text(
        json.dumps(
            {
                "env_id": env,
                "objective": objective,
                "config": {"plan": plan, "context": context, **settings},
                "mean_curve": curve,
                "split_seed": split,
                "tasks": list(tasks),
            }  # fmt: skip
        )
    )
    return str(path)


def test_compare_relative_enhancement_by_hand(tmp_path):
    base = [
        fake_eval(tmp_path / f"b{i}", "ad", c) for i, c in enumerate([[1, 3], [2, 2]])
    ]  # means 2, 2
    lhf = [
        fake_eval(tmp_path / f"l{i}", "ad", c) for i, c in enumerate([[2, 4], [3, 5]])
    ]  # means 3, 4
    r = compare(base, lhf, tmp_path / "cmp")
    row = r["rows"][0]
    assert row["backbone"] == "AD" and row["baseline_mean"] == 2 and row["lhf_mean"] == 3.5
    assert np.isclose(row["E"], (3.5 - 2) / 2)
    # the sample std (n - 1) of the per-run E: (3-2)/2, (4-2)/2
    assert np.isclose(row["E_std"], np.std([0.5, 1.0], ddof=1))
    # 95% interval of E itself (delta method): d = 1, 2 (mean 1.5, s_d^2 = 0.5), b = 2, 2 (no
    # spread): Var(E) = (0.5 / 2^2) / 2 = 0.0625, E 0.75 +- t(0.975, 1) x 0.25, t = 12.706
    half = 12.7062 * 0.25
    assert np.allclose(row["E_interval95"], [0.75 - half, 0.75 + half], atol=1e-4)
    assert row["E_note"] is None  # 2 is not near zero on Darkroom (mean optimal return 16.5)
    # the paired return differences 3 - 2, 4 - 2: mean 1.5, s = 0.7071, the verdict's interval
    assert row["baseline_run_means"] == [2, 2] and row["lhf_run_means"] == [3, 4]
    half = 12.7062 * np.std([1.0, 2.0], ddof=1) / np.sqrt(2)
    assert row["diff"] == 1.5 and np.allclose(row["diff_ci95"], [1.5 - half, 1.5 + half], atol=1e-4)
    assert "| AD | 2.00 ± 0.00 | 3.50 ± 0.71 | +75.0 ± 35.4 |" in r["table"]
    assert r["table"].rstrip().endswith(f"| 2/2 | +1.50 ({1.5 - half:+.2f} .. {1.5 + half:+.2f}) |")
    assert (tmp_path / "cmp" / "compare.png").stat().st_size > 0
    assert (tmp_path / "cmp" / "compare.md").read_text().startswith("| darkroom |")


def test_the_interval_of_e_is_of_the_e_printed_and_a_near_zero_baseline_is_flagged(tmp_path):
    """Three paired runs, by hand: b = 10, 12, 8 and f = 12, 13, 10: E = 11.667 / 10 - 1 = 0.1667;
    d = 2, 1, 2 (mean 5/3, s_d^2 = 1/3), s_b^2 = 4, s_db = -1: Var(E) = (1/3 / 100 + (25/9) x 4 /
    10^4 + 2 x (5/3) / 10^3) / 3 = 0.0025926, half = t(0.975, 2) 4.3027 x 0.050918 = 0.21908."""
    base = [fake_eval(tmp_path / f"b{i}", "ad", [v, v]) for i, v in enumerate([10, 12, 8])]
    lhf = [fake_eval(tmp_path / f"l{i}", "ad", [v, v]) for i, v in enumerate([12, 13, 10])]
    row = compare(base, lhf)["rows"][0]
    assert np.isclose(row["E"], 1 / 6)
    assert np.allclose(row["E_interval95"], [1 / 6 - 0.21908, 1 / 6 + 0.21908], atol=1e-4)
    # minimum detectable difference at 80 % power: (t(0.975, 2) 4.3027 + t(0.8, 2) 1.0607) x
    # s_d 0.57735 / sqrt(3) = 1.7879; over the baseline's 10: E 0.179
    assert np.isclose(row["diff_mde80"], 1.7879, atol=1e-3)
    assert np.isclose(row["E_mde80"], 0.17879, atol=1e-4)
    assert np.isclose(row["baseline_std"], 2.0) and np.isclose(
        row["lhf_std"], np.std([12, 13, 10], ddof=1)
    )
    # one run a side measures no spread: no std (not 0), and the table prints none
    one = compare(base[:1], lhf[:1])
    assert one["rows"][0]["baseline_std"] is None and one["rows"][0]["lhf_std"] is None
    assert "| AD | 10.00 | 12.00 |" in one["table"] and "± 0.00" not in one["table"]
    # the same differences on a baseline near zero (below 10 % of Darkroom's 16.5): flagged
    base = [fake_eval(tmp_path / f"z{i}", "ad", [v, v]) for i, v in enumerate([0.4, 0.5, 0.45])]
    lhf = [fake_eval(tmp_path / f"y{i}", "ad", [v, v]) for i, v in enumerate([0.6, 0.7, 0.8])]
    r = compare(base, lhf)
    assert "near zero" in r["rows"][0]["E_note"] and "(baseline near 0)" in r["table"]
    # Meta-World knows no optimal return: never flagged
    mw = {"env": "metaworld-reach-wall", "tasks": (0, 1)}
    base = [fake_eval(tmp_path / f"m{i}", "ad", [v, v], **mw) for i, v in enumerate([0.4, 0.5])]
    lhf = [fake_eval(tmp_path / f"n{i}", "ad", [v, v], **mw) for i, v in enumerate([0.6, 0.7])]
    assert compare(base, lhf)["rows"][0]["E_note"] is None


def test_compare_errors(tmp_path):
    a = fake_eval(tmp_path / "a", "ad", [1, 2])
    with pytest.raises(ValueError, match="different envs"):
        compare([a], [fake_eval(tmp_path / "b", "ad", [1, 2], env="darkroom-large")])
    with pytest.raises(ValueError, match="numbers of episodes"):
        compare([a], [fake_eval(tmp_path / "c", "ad", [1, 2, 3])])
    with pytest.raises(ValueError, match="backbones differ"):
        compare([a], [fake_eval(tmp_path / "d", "dpt", [1, 2])])
    with pytest.raises(ValueError, match="no baseline"):
        compare([], [a])
    with pytest.raises(FileNotFoundError, match="eval_results.json"):
        compare([a], [str(tmp_path / "missing")])
    # runs that measure different things are refused, naming the difference
    with pytest.raises(ValueError, match="different context protocols"):
        compare([a], [fake_eval(tmp_path / "w", "ad", [1, 2], context="window")])
    with pytest.raises(ValueError, match="differ in split or tasks"):
        compare([a], [fake_eval(tmp_path / "s", "ad", [1, 2], split=1)])
    with pytest.raises(ValueError, match="differ in split or tasks"):
        compare([a], [fake_eval(tmp_path / "t", "ad", [1, 2], tasks=(3, 6))])
    b1 = fake_eval(tmp_path / "b1", "ad", [1, 2], split=1, tasks=(4,))
    with pytest.raises(ValueError, match="different splits or task sets"):
        compare([a, b1], [fake_eval(tmp_path / "u", "ad", [1, 2], split=2)])
    # other evaluation settings within a backbone: refused, naming the setting and every run
    a2, a3 = fake_eval(tmp_path / "a2", "ad", [1, 2]), fake_eval(tmp_path / "a3", "ad", [1, 2])
    with pytest.raises(ValueError, match=r"AD runs were evaluated with different settings: rollouts=1 \(.*/a, .*/a2, .*/a3\); rollouts=4 \(.*/r4\)$"):  # fmt: skip
        compare([a, a2], [fake_eval(tmp_path / "r4", "ad", [1, 2], rollouts=4), a3])
    # one run on both sides (a folder and its results file are the same run) would give E = 0
    with pytest.raises(ValueError, match=r"/a/eval_results.json and .*/a are the same evaluation run"):  # fmt: skip
        compare([a], [f"{a}/eval_results.json"])
    with pytest.raises(ValueError, match="are the same evaluation run"):
        compare([a, a], [a2, a3])
    # a planning variant is its own row: a gated run is never compared with the reference's
    ref = {"plan_ties": "index", "plan_order": "sample"}  # the reference planner's
    p1 = fake_eval(tmp_path / "p1", "dicp", [1, 2], plan=True, **ref)
    with pytest.raises(ValueError, match=r"baseline \['DICP \+ plan'\] and LHF \['DICP \+ plan, gated'\]"):  # fmt: skip
        compare([p1], [fake_eval(tmp_path / "p2", "dicp", [1, 2], plan=True, plan_gate="reward_seen", **ref)])  # fmt: skip
    # a planned run written before plan_ties existed broke ties by the policy: that variant's row
    old = fake_eval(tmp_path / "p0", "dicp", [1, 2], plan=True, plan_order="sample")
    with pytest.raises(ValueError, match=r"baseline \['DICP \+ plan, ties by policy'\] and LHF \['DICP \+ plan'\]"):  # fmt: skip
        compare([old], [p1])
    # one written before plan_order existed took depth-0 ties in the policy's argmax order
    older = fake_eval(tmp_path / "p00", "dicp", [1, 2], plan=True)
    with pytest.raises(ValueError, match=r"\['DICP \+ plan, argmax order, ties by policy'\] and LHF \['DICP \+ plan'\]"):  # fmt: skip
        compare([older], [p1])
    # Meta-World's greedy search has no ties to order: no suffix for either field
    mw = fake_eval(tmp_path / "mw", "dicp", [1, 2], env="metaworld-reach", plan=True)
    assert backbone_of(json.loads((Path(mw) / "eval_results.json").read_text())) == "DICP + plan"
    # a damaged or hand-edited result is named, with what is wrong
    bad = tmp_path / "bad"
    for name, text, why in [
        ("empty", "", "not readable JSON"),
        ("list", "[1]", "not a JSON object"),
        ("noconfig", '{"objective": "ad", "env_id": "darkroom", "mean_curve": [1]}', "no 'config'"),
        ("r0", '{"objective": "ad", "env_id": "darkroom", "mean_curve": [1], "config": {"rollouts": 0}}', "rollouts must be an integer >= 1, got 0"),
        ("rstr", '{"objective": "ad", "env_id": "darkroom", "mean_curve": [1], "config": {"rollouts": "1"}}', "got '1'"),
        ("nan", '{"objective": "ad", "env_id": "darkroom", "mean_curve": [1, NaN], "config": {}}', "not a finite number"),
        ("text", '{"objective": "ad", "env_id": "darkroom", "mean_curve": [1, "2"], "config": {}}', "not a finite number"),
    ]:  # fmt: skip
        (bad / name).mkdir(parents=True)
        (bad / name / "eval_results.json").write_text(text)
        with pytest.raises(ValueError, match=f"{name}/eval_results.json: .*{why}"):
            compare([a], [str(bad / name)])
    with pytest.raises(ValueError, match=r"LHF \['DICP \+ plan, true dynamics'\]"):
        compare([p1], [fake_eval(tmp_path / "p3", "dicp", [1, 2], plan=True, plan_dynamics="oracle", **ref)])  # fmt: skip
    with pytest.raises(ValueError, match=r"LHF \['DICP \+ plan, reward p >= 0.9'\]"):
        compare([p1], [fake_eval(tmp_path / "p4", "dicp", [1, 2], plan=True, plan_reward_threshold=0.9, **ref)])  # fmt: skip
    # planner settings do not matter without planning; the defaults match results written before
    r = compare([fake_eval(tmp_path / "n1", "dicp", [1, 2])],
                [fake_eval(tmp_path / "n2", "dicp", [2, 2], plan_gate="reward_seen", rollouts=1)])  # fmt: skip
    assert np.isclose(r["rows"][0]["E"], 2 / 1.5 - 1)
    # cache and recompute are the same function: comparable; so are runs paired in order
    r = compare([a], [fake_eval(tmp_path / "r", "ad", [2, 2], context="recompute")])
    assert np.isclose(r["rows"][0]["E"], 2 / 1.5 - 1)


@pytest.mark.slow
def test_cli_evaluate_and_compare(tmp_path, capsys):
    darkroom_model("ad").save_pretrained(tmp_path / "m")
    assert (
        main(
            [
                "evaluate",
                "--model",
                str(tmp_path / "m"),
                "--episodes",
                "2",
                "--out",
                str(tmp_path / "e"),
            ]
        )
        == 0
    )
    assert "mean return" in capsys.readouterr().out
    # the same run on both sides is refused (E = 0 would read as "no effect"); a copy compares
    assert main(["compare", "--baseline", str(tmp_path / "e"), "--lhf", str(tmp_path / "e")]) == 1
    assert "are the same evaluation run" in capsys.readouterr().err
    shutil.copytree(tmp_path / "e", tmp_path / "e-copy")
    assert main(["compare", "--baseline", str(tmp_path / "e"), "--lhf", str(tmp_path / "e-copy")]) == 0  # fmt: skip
    assert "+0.0" in capsys.readouterr().out
    assert (
        main(["evaluate", "--model", str(tmp_path / "m"), "--plan", "--out", str(tmp_path / "x")])
        == 1
    )
    assert "dynamics heads" in capsys.readouterr().err
    # --context reaches the rollout and the results
    for flags, mode in [
        (["--context", "recompute"], "recompute"),
        (["--context", "window"], "window"),
        (["--context", "cache"], "cache"),
    ]:
        out = tmp_path / f"e-{mode}"
        args = ["evaluate", "--model", str(tmp_path / "m"), "--episodes", "2", "--out", str(out)]
        assert main(args + flags) == 0
        saved = json.loads((out / "eval_results.json").read_text())
        assert saved["config"]["context"] == mode
    base = json.loads((tmp_path / "e" / "eval_results.json").read_text())
    assert base["config"]["context"] == "auto" and base["context"] == "window"
    window = json.loads((tmp_path / "e-window" / "eval_results.json").read_text())
    assert window["returns"] == base["returns"]  # auto is the window-trained model's semantics
    cache = json.loads((tmp_path / "e-cache" / "eval_results.json").read_text())
    recompute = json.loads((tmp_path / "e-recompute" / "eval_results.json").read_text())
    assert cache["returns"] == recompute["returns"] and cache["engine"] == "lean"  # one function


@pytest.mark.slow
@pytest.mark.metaworld
def test_metaworld_rollout_with_greedy_planning():
    pytest.importorskip("metaworld")
    cfg = model_config_for(
        get_spec("metaworld-reach"),
        TrainConfig(dataset="-", objective="dicp", out="-", preset="tiny", context_length=50),
        False,
    )
    torch.manual_seed(0)
    model = ICRLModel(cfg).eval()
    batch = make_task_batch("metaworld-reach", [50, 51], 0, 0)
    r = rollout(model, batch, 2, seed=0, plan=True, progress=False, record_actions=True)
    assert r.returns.shape == (2, 2) and r.success.shape == (2, 2)
    # greedy planning only in each episode's second half (the context of 50 is full by then)
    assert r.planned_steps == 2 * 50 and r.planned_actions == 2 * 2 * 50
    assert np.all(np.abs(r.actions) <= 1)
    with pytest.raises(ValueError, match="gates the beam search of discrete-action envs"):
        rollout(model, batch, 1, plan=True, plan_gate="reward_seen", progress=False)
    with pytest.raises(ValueError, match="plan_ties orders the beam search of discrete actions"):
        rollout(model, batch, 1, plan=True, plan_ties="policy", progress=False)


def test_compare_with_a_zero_baseline_writes_valid_json(tmp_path):
    """E divides by the baseline's return: at 0 it is undefined, said in the table and JSON (no
    NaN, which is not JSON), and the paired differences still judge the cell."""
    base = [fake_eval(tmp_path / f"b{i}", "ad", [0, 0]) for i in range(2)]
    lhf = [fake_eval(tmp_path / f"l{i}", "ad", c) for i, c in enumerate([[1, 1], [2, 2]])]
    r = compare(base, lhf, tmp_path / "cmp")
    text = (tmp_path / "cmp" / "compare.json").read_text()
    row = json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in compare.json"))["rows"][0]
    assert row["E"] is None and "baseline's mean return is 0" in row["E_note"]
    assert row["E_std"] is None and row["diff"] == 1.5
    assert "| AD | 0.00 ± 0.00 | 1.50 ± 0.71 | undefined (baseline 0) |" in r["table"]
    from lhf_hf.reproduce.report import verdict

    # the paired differences (1, 2) judge the cell although E is undefined; without them, nothing
    assert verdict(row) == "no clear effect (the paired return difference's 95% CI spans 0)"
    assert verdict({**row, "diff_ci95": None}) == "undefined (baseline return 0)"
