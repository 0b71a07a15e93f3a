"""lhf reproduce --estimate: units x a seconds-per-unit rate from this work folder, else rates.json."""

from __future__ import annotations

import json
import time

import pytest

from lhf_hf.collection.backend_verdict import cpu_model
from lhf_hf.configs import CollectConfig, EvalConfig, TrainConfig
from lhf_hf.reproduce import estimate_experiment, export_experiment, reproduce
from lhf_hf.reproduce.estimate import (
    collect_cost,
    duration,
    estimate,
    eval_cost,
    measured,
    reference_rates,
    render,
    train_cost,
    twin_keys,
)
from lhf_hf.reproduce.stages import DONE_FILE, Cost, Stage, StageRunner


def _noop(out):
    pass


def _graph():
    col = Stage("collect", "collect", {"i": 0}, _noop, cost=Cost("collect|x", 1000))
    tb = Stage("train", "train base", {"i": 1}, _noop, (col,), Cost("train|x", 50))
    fil = Stage("filter", "filter", {"i": 2}, _noop, (col,), Cost("filter", 1000))
    tl = Stage("train", "train lhf", {"i": 3}, _noop, (col, fil), Cost("train|x", 50))
    eb = Stage("evaluate", "eval base", {"i": 4}, _noop, (tb,), Cost("evaluate|x", 10))
    el = Stage("evaluate", "eval lhf", {"i": 5}, _noop, (tl,), Cost("evaluate|x", 10))
    col2 = Stage("collect", "collect 2", {"i": 6}, _noop, cost=Cost("collect|x", 1000))
    return [col, tb, fil, tl, eb, el, col2]


def _record(work, stage, wall, cpu=None, **extra):
    out = stage.path(work)
    out.mkdir(parents=True)
    rec = {"kind": stage.kind, "label": stage.label, "config": stage.config, "wall_s": wall,
           "cost": {"key": stage.cost.key, "units": stage.cost.units}, "cpu": cpu or cpu_model(),
           **extra}  # fmt: skip
    (out / DONE_FILE).write_text(json.dumps(rec))


def test_rates_here_first_then_the_reference_and_what_has_none_is_said(tmp_path):
    stages = _graph()
    _record(tmp_path, stages[0], 10.0)  # collect: cached, and a rate of 0.01 s per transition
    ref = {"train|x": {"key": "train|x", "seconds_per_unit": 2.0, "overhead_s": 5.0, "cpu": "Ref"},
           "collect|x": {"key": "collect|x", "seconds_per_unit": 9.0, "cpu": "Ref"}}  # fmt: skip
    est = estimate(stages, tmp_path, jobs=1, reference=ref)
    rows = {r["label"]: r for r in est["stages"]}
    assert rows["collect"]["cached"] and rows["collect"]["seconds"] is None
    assert rows["collect 2"]["seconds"] == pytest.approx(10.0)  # here before the reference
    assert rows["collect 2"]["basis"] == "here, 1 stage(s)"
    assert rows["train base"]["seconds"] == pytest.approx(105.0)  # 5 + 50 units x 2.0
    assert rows["train base"]["basis"] == "reference, Ref"
    assert est["to_run"] == 6 and est["missing"] == ["evaluate|x", "filter"]
    assert est["wall_s"] == pytest.approx(220.0) == est["stage_s"]
    # --jobs 2: the in-process stages one after the other, the others spread over the jobs
    assert estimate(stages, tmp_path, jobs=2, reference=ref)["wall_s"] == pytest.approx(115.0)
    text = render(est, "head")
    assert "[1/7] collect  collect: cached" in text
    assert "train base: to run, ~1.8 min (reference, Ref)" in text
    assert "eval base: to run, ? (no measured rate for evaluate|x)" in text
    assert "6 of 7 stage(s) to run: at least ~3.7 min wall with --jobs 1" in text
    assert "2 kind(s) of stage never measured" in text


def test_only_whole_stages_of_this_cpu_model_are_rates(tmp_path):
    a, b, c, d = (Stage("train", k, {"i": k}, _noop, cost=Cost("train|x", 100)) for k in "abcd")
    _record(tmp_path, a, 10.0)
    _record(tmp_path, b, 30.0)
    _record(tmp_path, c, 99.0, cpu="another CPU")
    _record(tmp_path, d, 99.0, resumed=True)  # its wall time covers part of its work
    (tmp_path / "train" / "broken").mkdir()
    (tmp_path / "train" / "broken" / DONE_FILE).write_text("{")  # no record: no rate
    assert measured(tmp_path) == {"train|x": {"seconds": 40.0, "units": 200.0, "stages": 2}}


def test_a_resumed_stage_records_that_it_resumed(tmp_path):
    def work(out):
        time.sleep(0.15)  # a wall time that rounds above 0
        (out / "result").write_text("done")

    s = Stage("train", "t", {"i": 1}, work, cost=Cost("train|x", 100))
    (s.path(tmp_path) / "model").mkdir(parents=True)  # an interrupted call left a checkpoint
    StageRunner(tmp_path, echo=lambda m: None).run(s)
    assert json.loads((s.path(tmp_path) / DONE_FILE).read_text())["resumed"] is True
    assert measured(tmp_path) == {}
    StageRunner(tmp_path, echo=lambda m: None).run(Stage("train", "f", {"i": 2}, work, cost=s.cost))
    assert measured(tmp_path)["train|x"]["stages"] == 1


def test_the_reference_takes_this_cpu_model_s_table_first(tmp_path):
    path = tmp_path / "rates.json"
    path.write_text(json.dumps({"machines": [
        {"cpu": "A", "rates": [{"key": "k", "seconds_per_unit": 1.0, "stages": 1},
                               {"key": "only A", "seconds_per_unit": 3.0, "stages": 1}]},
        {"cpu": "B", "rates": [{"key": "k", "seconds_per_unit": 2.0, "stages": 1}]},
    ]}))  # fmt: skip
    rates = reference_rates(path, cpu="B")
    assert (rates["k"]["seconds_per_unit"], rates["k"]["cpu"]) == (2.0, "B")
    assert rates["only A"]["cpu"] == "A"  # what this machine's table lacks: the others'
    assert reference_rates(path, cpu="C")["k"]["cpu"] == "A"
    assert reference_rates(tmp_path / "none.json") == {}
    # the shipped table reads, and names a rate for the main job's stages
    assert "collect|darkroom|batched|ppo" in reference_rates()


def test_twins_lend_their_rates_and_say_so():
    assert ("train|metaworld-reach-wall|dicp|ctx500", "metaworld-reach-wall") in twin_keys(
        "train|metaworld-reach|dicp|ctx500"
    )
    assert twin_keys("train|darkroom|ad") == []  # gridworld variants declare no cost class
    assert twin_keys("filter") == [] and twin_keys("train|no-such-env|ad") == []
    ref = {"train|metaworld-reach-wall|dicp": {"seconds_per_unit": 2.0, "cpu": "A"}}
    s = Stage("train", "t", {}, _noop, cost=Cost("train|metaworld-push|dicp", 10))
    (row,) = estimate([s], "/nonexistent", reference=ref)["stages"]
    assert (
        row["seconds"] == 20.0 and row["basis"] == "reference, A, measured on metaworld-reach-wall"
    )


def test_costs_by_hand():
    c = collect_cost(
        CollectConfig(env_id="darkroom", tasks="train", histories=20, collector="batched")
    )
    assert c == Cost("collect|darkroom|batched|ppo", 73 * 20 * 1000)
    tr = TrainConfig(dataset="-", out="-", objective="dicp", preset="paper", max_steps=100)
    # 100 steps x batch 64 (default) x context 80 x 2 tokens per transition (DICP)
    assert train_cost("darkroom", tr) == Cost("train|darkroom|dicp|paper|window", 100 * 64 * 160)
    ev = EvalConfig(model="-", out="-", episodes=10)
    assert eval_cost("darkroom", "dicp", tr, ev, 0) == Cost(
        "evaluate|darkroom|dicp|paper|no plan|window", 8 * 10 * 20
    )
    # planned: the steps after the context (K = 80) is full, 8 tasks x (200 - 80), per rollout
    planned = EvalConfig(model="-", out="-", episodes=10, plan=True, rollouts=4)
    assert eval_cost("darkroom", "dicp", tr, planned, 0) == Cost(
        "evaluate|darkroom|dicp|paper|plan|window", 4 * 8 * 120
    )
    # continuous actions: every step counts; a context other than the env's default is named
    mw = TrainConfig(dataset="-", out="-", objective="dicp", preset="paper", context_length=500)
    mw_ev = EvalConfig(model="-", out="-", episodes=7, plan=True)
    assert eval_cost("metaworld-reach-wall", "dicp", mw, mw_ev, 0) == Cost(
        "evaluate|metaworld-reach-wall|dicp|paper|plan|window|ctx500", 50 * 7 * 100
    )
    ctx80 = TrainConfig(dataset="-", out="-", objective="dicp", preset="paper", context_length=80)
    assert train_cost("darkroom", ctx80).key == "train|darkroom|dicp|paper|window"  # its default
    band = TrainConfig(dataset="-", out="-", objective="ad", preset="paper", attention="band")
    assert eval_cost("darkroom", "ad", band, ev, 0).key.endswith("|cache")


def test_durations_read_at_a_glance():
    assert duration(45) == "45 s"
    assert duration(600) == "10.0 min"
    assert duration(5399) == "1.5 h" and duration(5370) == "89.5 min"
    assert duration(47 * 3600) == "47.0 h"
    assert duration(3000 * 3600) == "125.0 days"  # the paper preset on 2 cores


def test_jobs_and_the_work_folder_are_checked(tmp_path):
    for bad in (0, -1, 2.5, "2", True):
        with pytest.raises(ValueError, match="jobs must be an integer >= 1"):
            estimate_experiment("darkroom-main", "cpu", jobs=bad)
        with pytest.raises(ValueError, match="jobs must be an integer >= 1"):
            reproduce("darkroom-main", "cpu", jobs=bad)
    f = tmp_path / "stage.json"
    f.write_text("{}")
    for work in (f, "", "  "):
        with pytest.raises(ValueError, match="not a stage cache folder|--work"):
            estimate_experiment("darkroom-main", "quick", work=work)
        with pytest.raises(ValueError, match="not a stage cache folder|--work"):
            reproduce("darkroom-main", "quick", work=work, out=tmp_path / "r")
        with pytest.raises(ValueError, match="not a stage cache folder|--work"):
            export_experiment("darkroom-main", tmp_path / "x", "quick", work=work)
    assert not (tmp_path / "r").exists() and not (tmp_path / "x").exists()


def test_the_main_job_has_an_estimate_from_the_shipped_rates(tmp_path):
    text = estimate_experiment("darkroom-noisy", "quick", work=tmp_path / "w", jobs=2)
    assert "report in results/darkroom-noisy-quick" in text
    assert "to run: ~" in text and "never measured" not in text
