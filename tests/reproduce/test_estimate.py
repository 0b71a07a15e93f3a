"""lhf reproduce --estimate: rates from finished stages, the reference table, the schedule."""

from __future__ import annotations

import json
import time

import pytest

from lhf_hf.collection.backend_verdict import cpu_model
from lhf_hf.reproduce.estimate import (
    THREAD_FACTOR,
    estimate,
    find_rate,
    measured_stages,
    rate_table,
    render,
    schedule,
)
from lhf_hf.reproduce.stages import COST_FORMAT, DONE_FILE, RECORD_FILE, Cost, Stage


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


SECONDS = [10, 100, 1, 100, 5, 5, 10]


def test_schedule_by_hand():
    stages = _graph()
    d = {s.hash: t for s, t in zip(stages, SECONDS, strict=True)}
    assert schedule(stages, d, set(), jobs=1) == 231
    # jobs 2: collect alone (0-10); train base from 10; the filter here (10-11); train lhf from
    # 11; eval base 110-115, eval lhf 111-116; the second collection waits for both: 116-126
    assert schedule(stages, d, set(), jobs=2) == 126
    # cached stages take no time and release their dependants at once
    assert schedule(stages, d, {stages[0].hash, stages[2].hash}, jobs=2) == 100 + 5 + 10
    assert schedule(stages, d, {s.hash for s in stages}, jobs=2) == 0


def test_collections_start_first_so_a_later_run_is_not_held_back():
    # two runs, each a collection (10 s) and two trainings (100 s), on 4 jobs: in plan order the
    # second collection waited for the first run's trainings (0-10, 10-110, 110-120, 120-220)
    runs = []
    for r in range(2):
        col = Stage("collect", f"collect {r}", {"r": r}, _noop, cost=Cost("collect|x", 1))
        runs += [col] + [
            Stage("train", f"train {r}{a}", {"r": r, "a": a}, _noop, (col,), Cost("train|x", 1))
            for a in "bl"
        ]
    d = {s.hash: (10 if s.kind == "collect" else 100) for s in runs}
    assert schedule(runs, d, set(), jobs=4) == 10 + 10 + 100
    from lhf_hf.reproduce.parallel import start_order

    assert [s.label for s in start_order(runs)] == [
        "collect 0", "collect 1", "train 0b", "train 0l", "train 1b", "train 1l"
    ]  # fmt: skip


def _record(work, stage, wall, threads, cpu):
    out = stage.path(work)
    out.mkdir(parents=True)
    rec = {"kind": stage.kind, "label": stage.label, "config": stage.config, "wall_s": wall}
    rec.update(cost={"key": stage.cost.key, "units": stage.cost.units}, cpu=cpu, threads=threads)
    (out / DONE_FILE).write_text(json.dumps(rec))


def test_rates_from_finished_stages_the_reference_and_thread_counts(tmp_path):
    here = cpu_model()
    a = Stage("train", "a", {"i": "a"}, _noop, cost=Cost("train|x", 100))
    b = Stage("train", "b", {"i": "b"}, _noop, cost=Cost("train|x", 300))
    c = Stage("collect", "c", {"i": "c"}, _noop, cost=Cost("collect|x", 1000))
    other = Stage("train", "o", {"i": "o"}, _noop, cost=Cost("train|x", 100))
    _record(tmp_path, a, 20.0, 2, here)  # 0.2 s per unit
    _record(tmp_path, b, 120.0, 2, here)  # 0.4 s per unit
    _record(tmp_path, c, 5.0, 2, here)
    _record(tmp_path, other, 999.0, 2, "another CPU")  # never used for this machine
    old = tmp_path / "train" / "old"
    old.mkdir()
    (old / DONE_FILE).write_text(json.dumps({"kind": "train", "wall_s": 3}))  # no cost: skipped
    copied = tmp_path / "train" / "copied"  # another stage's record copied in: not this one's
    copied.mkdir()
    (copied / DONE_FILE).write_bytes((a.path(tmp_path) / DONE_FILE).read_bytes())
    records = measured_stages(tmp_path)
    assert len(records) == 4
    table = rate_table(records)
    # seconds over units: (20 + 120) / (100 + 300), not the mean of 0.2 and 0.4
    assert table[("train|x", here, 2)] == {
        "seconds_per_unit": pytest.approx(0.35),
        "overhead_s": 0.0,  # no training log to tell the steps' time from the start-up
        "stages": 2,
        "units": 400.0,
    }
    ref = {"cpu": "Reference CPU", "rates": [{"key": "evaluate|x", "threads": 2,
                                               "seconds_per_unit": 0.5, "stages": 3}]}  # fmt: skip
    r = find_rate("train|x", 2, table, here, ref)
    assert r.seconds_per_unit == pytest.approx(0.35) and r.basis == "here"
    # one thread (--jobs 2): the measured 2-thread rate times the side-by-side factor
    r1 = find_rate("train|x", 1, table, here, ref)
    assert r1.seconds_per_unit == pytest.approx(0.35 * THREAD_FACTOR)
    assert r1.basis == "here, 2-thread rate x 1.53"
    # a collection does not depend on torch's threads
    assert find_rate("collect|x", 1, table, here, ref).seconds_per_unit == pytest.approx(0.005)
    # not measured here: the reference; not anywhere: None
    # a collection that ran with another thread count pools with it (one rate, any count)
    c1 = Stage("collect", "c1", {"i": "c1"}, _noop, cost=Cost("collect|x", 1000))
    _record(tmp_path, c1, 15.0, 1, here)
    pooled = rate_table(measured_stages(tmp_path))[("collect|x", here, 0)]
    assert pooled["stages"] == 2 and pooled["seconds_per_unit"] == pytest.approx(0.01)
    # a training measured at 1 and 4 threads, asked at 2: the nearest count (1) is converted
    t4 = {("train|y", here, 4): {"seconds_per_unit": 9.0, "stages": 1},
          ("train|y", here, 1): {"seconds_per_unit": 3.0, "stages": 1}}  # fmt: skip
    r2 = find_rate("train|y", 2, t4, here, ref)
    assert r2.seconds_per_unit == pytest.approx(3.0 / THREAD_FACTOR)
    assert r2.basis == "here, 1-thread rate x 0.65"
    rr = find_rate("evaluate|x", 2, table, here, ref)
    assert rr.seconds_per_unit == 0.5 and rr.basis == "reference"
    assert find_rate("train|never", 2, table, here, ref) is None


def test_reference_of_a_like_machine_first_and_the_others_for_what_it_lacks(tmp_path):
    from lhf_hf.reproduce.estimate import load_reference

    def machine(cpu, isa, rates):
        return {"cpu": cpu, "isa": isa, "rates": [
            {"key": k, "threads": 1, "seconds_per_unit": v, "stages": 1} for k, v in rates.items()
        ]}  # fmt: skip

    intel = machine("Intel X", "avx512", {"train|a": 1.0, "evaluate|b": 3.0})
    amd = machine("AMD Y", "avx2", {"train|a": 2.0})
    path = tmp_path / "rates.json"
    path.write_text(json.dumps({"machines": [intel, amd]}))
    # an AVX2 machine of another model: the AVX2 table first, the Intel one for what it lacks
    ref = load_reference(path, cpu="AMD Z", isa="avx2")
    assert ref["cpu"] == "AMD Y"
    r = find_rate("train|a", 1, {}, "AMD Z", ref)
    assert (r.seconds_per_unit, r.basis) == (2.0, "reference")
    r = find_rate("evaluate|b", 1, {}, "AMD Z", ref)
    assert (r.seconds_per_unit, r.basis) == (3.0, "reference, Intel X")
    # the instruction set wins over the model name: "AMD EPYC" names a Zen 4 with AVX-512 and an
    # AVX2-only machine, ~2x apart; model and instruction set together win over either
    assert load_reference(path, cpu="Intel X", isa="avx2")["cpu"] == "AMD Y"
    assert load_reference(path, cpu="Intel X", isa="avx512")["cpu"] == "Intel X"
    assert load_reference(path, cpu="Intel X", isa="other")["cpu"] == "Intel X"
    # this CPU's table without an instruction set (older) is this machine's: it ranks after the
    # exact match and before another CPU of the same set, whatever the order in the file
    no_isa = {**machine("Intel X", "?", {"train|a": 5.0})}
    no_isa.pop("isa")
    other_set = machine("Intel X", "avx2", {"train|a": 6.0})
    same_set = machine("AMD Y", "avx512", {"train|a": 7.0})
    for order in ([no_isa, other_set, same_set], [same_set, other_set, no_isa]):
        path.write_text(json.dumps({"machines": order}))
        assert (
            load_reference(path, cpu="Intel X", isa="avx512")["rates"][0]["seconds_per_unit"] == 5.0
        )
    path.write_text(json.dumps({"machines": [no_isa, intel]}))
    assert load_reference(path, cpu="Intel X", isa="avx512")["rates"][0]["seconds_per_unit"] == 1.0
    # numbers too large for a float, or non-string names: refused, not an OverflowError
    for bad in ({"rates": [{"key": "k", "threads": 1, "seconds_per_unit": 10**400, "stages": 1}]},
                {"command": 5, "rates": []}, {"date": ["x"], "rates": []}):  # fmt: skip
        path.write_text(json.dumps(bad))
        with pytest.raises(ValueError, match="not a rates table"):
            load_reference(path)
    zen4 = machine("AMD EPYC", "avx512", {"train|a": 1.0})
    zen2 = machine("AMD EPYC", "avx2", {"train|a": 2.0})
    path.write_text(json.dumps({"machines": [zen4, zen2]}))
    assert load_reference(path, cpu="AMD EPYC", isa="avx2")["rates"][0]["seconds_per_unit"] == 2.0
    # a malformed table: an error naming the file, not a traceback from deep inside
    for bad in ("{}", "[]", '{"machines": [{"rates": [{"key": "k"}]}]}'):
        path.write_text(bad)
        with pytest.raises(ValueError, match="rates.json: not a rates table"):
            load_reference(path)
    path.write_text(json.dumps({"machines": [intel, amd]}))
    # the single-machine form (older rates.json) still reads; no file: no rates
    path.write_text(json.dumps(intel))
    assert load_reference(path, cpu="AMD Z", isa="avx2")["cpu"] == "Intel X"
    assert load_reference(tmp_path / "none.json") == {"cpu": "?", "rates": []}
    # the shipped table parses, and names its machines
    from lhf_hf.reproduce.estimate import REFERENCE, reference_machines

    shipped = reference_machines(json.loads(REFERENCE.read_text()))
    assert shipped and all(m["cpu"] and m["rates"] for m in shipped)


def test_estimate_skips_cached_stages_and_says_what_it_cannot_time(tmp_path, monkeypatch):
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    stages = _graph()
    _record(tmp_path, stages[0], 10.0, 2, cpu_model())  # collect: cached, and a rate
    ref = {"cpu": "Ref", "rates": [{"key": "train|x", "threads": 2, "seconds_per_unit": 2.0,
                                    "stages": 1}]}  # fmt: skip
    est = estimate(stages, tmp_path, jobs=1, reference=ref)
    rows = {r["label"]: r for r in est["stages"]}
    assert rows["collect"]["cached"] and rows["collect"]["seconds"] is None
    assert rows["collect 2"]["seconds"] == pytest.approx(10.0)  # same key, 1000 units
    assert rows["train base"]["seconds"] == pytest.approx(100.0)  # 50 units x 2.0 (reference)
    assert est["to_run"] == 6 and est["missing"] == ["evaluate|x", "filter"]
    assert est["wall_s"] == pytest.approx(210.0)
    text = render(est, "head")
    assert "[1/7] collect  collect: cached" in text
    assert "train base: to run, ~1.7 min (reference, 1 stage)" in text
    assert "'reference' = lhf_hf/reproduce/rates.json (Ref); 'reference, CPU' = a rate" in text
    assert "'N-thread rate x F' = measured at another torch thread count, converted (1.53x" in text
    assert "'measured on ENV' = a twin env's rate, this one's never measured" in text
    assert (
        "6 of 7 stages to run: at least ~3.5 min wall with --jobs 1, for the 3 with a rate; "
        "unknown for the other 3 (marked '?', 2 kinds of stage never measured"
    ) in text
    assert "exceeds the" not in text
    many = render(estimate(stages, tmp_path, jobs=64, reference=ref), "head")
    assert "--jobs 64 exceeds the" in many


def test_start_up_time_is_told_apart_from_the_work_that_scales(tmp_path):
    here = cpu_model()
    t = Stage("train", "t", {"i": "t"}, _noop, cost=Cost("train|x", 100))
    e = Stage("evaluate", "e", {"i": "e"}, _noop, cost=Cost("evaluate|x", 400))
    _record(tmp_path, t, 30.0, 1, here)  # 30 s in all, of which the Trainer's steps took 20 s
    (t.path(tmp_path) / "model").mkdir()
    log = [{"loss": 1.0, "step": 10}, {"train_runtime": 20.0, "step": 40}]
    (t.path(tmp_path) / "model" / "training_log.json").write_text(json.dumps(log))
    _record(tmp_path, e, 6.0, 1, here)  # one short episode: 5.5 of the 6 s are start-up
    (e.path(tmp_path) / "eval").mkdir()
    (e.path(tmp_path) / "eval" / "eval_results.json").write_text(json.dumps({"wall_s": 0.5}))
    table = rate_table(measured_stages(tmp_path))
    assert table[("train|x", here, 1)]["seconds_per_unit"] == pytest.approx(0.2)
    assert table[("train|x", here, 1)]["overhead_s"] == pytest.approx(10.0)
    r = find_rate("evaluate|x", 1, table, here, {"rates": []})
    assert (r.overhead_s, r.seconds_per_unit) == (pytest.approx(5.5), pytest.approx(0.5 / 400))
    # a 100-episode evaluation is not 100 x a one-episode stage: 5.5 + 100 x 0.5
    assert r.seconds(400 * 100) == pytest.approx(55.5)
    # a thread conversion scales the work, not the start-up
    r2 = find_rate("train|x", 2, table, here, {"rates": []})
    assert r2.seconds(100) == pytest.approx(10.0 + 20.0 / THREAD_FACTOR)


def test_costs_by_hand():
    from lhf_hf.configs import CollectConfig, EvalConfig, TrainConfig
    from lhf_hf.reproduce.estimate import collect_cost, eval_cost, train_cost

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
    # planned: the steps after the context (K = 80) is full, 8 tasks x (200 - 80)
    planned = eval_cost(
        "darkroom", "dicp", tr, EvalConfig(model="-", out="-", episodes=10, plan=True), 0
    )
    assert planned == Cost("evaluate|darkroom|dicp|paper|plan|window", 8 * 120)
    copies = EvalConfig(model="-", out="-", episodes=10, plan=True, rollouts=4)
    assert eval_cost("darkroom", "dicp", tr, copies, 0).units == 4 * 8 * 120  # each task 4 times
    # continuous actions: the greedy search costs about a model-free step, so every step counts
    # (Meta-World: 50 test tasks x 7 episodes x 100 steps)
    mw = TrainConfig(dataset="-", out="-", objective="dicp", preset="paper", context_length=500)
    mw_ev = EvalConfig(model="-", out="-", episodes=7, plan=True)
    # a context other than the env's default (Meta-World: 1,000) is named: a rate holds for one
    assert eval_cost("metaworld-reach-wall", "dicp", mw, mw_ev, 0) == Cost(
        "evaluate|metaworld-reach-wall|dicp|paper|plan|window|ctx500", 50 * 7 * 100
    )
    assert train_cost("metaworld-reach-wall", mw).key.endswith("|paper|window|ctx500")
    default = TrainConfig(dataset="-", out="-", objective="dicp", preset="paper")
    assert train_cost("metaworld-reach-wall", default).key.endswith("|paper|window")
    ctx80 = TrainConfig(dataset="-", out="-", objective="dicp", preset="paper", context_length=80)
    assert train_cost("darkroom", ctx80).key == "train|darkroom|dicp|paper|window"  # its default
    band = TrainConfig(dataset="-", out="-", objective="ad", preset="paper", attention="band")
    assert eval_cost("darkroom", "ad", band, ev, 0).key.endswith("|cache")  # auto: its semantics


def test_a_resumed_stage_records_no_rate(tmp_path):
    from lhf_hf.reproduce.stages import StageRunner

    def work(out):
        time.sleep(0.15)  # a wall time that rounds above 0
        (out / "result").write_text("done")

    s = Stage("train", "t", {"i": 1}, work, cost=Cost("train|x", 100))
    s.path(tmp_path).mkdir(parents=True)
    (s.path(tmp_path) / "model").mkdir()  # an interrupted earlier call left a checkpoint folder
    StageRunner(tmp_path, echo=lambda m: None).run(s)
    rec = json.loads((s.path(tmp_path) / DONE_FILE).read_text())
    assert rec["resumed"] and "cost" not in rec and measured_stages(tmp_path) == []
    fresh = Stage("train", "f", {"i": 2}, work, cost=Cost("train|x", 100))
    StageRunner(tmp_path, echo=lambda m: None).run(fresh)
    assert [r["label"] for r in measured_stages(tmp_path)] == ["f"]


def test_jobs_must_be_a_positive_integer():
    from lhf_hf.reproduce import estimate_experiment, reproduce

    for bad in (0, -1, 2.5, "2", True):
        with pytest.raises(ValueError, match="jobs must be an integer >= 1"):
            estimate_experiment("darkroom-main", "cpu", jobs=bad)
        with pytest.raises(ValueError, match="jobs must be an integer >= 1"):
            reproduce("darkroom-main", "cpu", jobs=bad)


def test_malformed_stage_records_are_no_rates_and_other_machines_are_left_out(tmp_path):
    from lhf_hf.collection.backend_verdict import instruction_set

    here, isa = cpu_model(), instruction_set()
    good = Stage("collect", "g", {"i": "g"}, _noop, cost=Cost("collect|x", 1000))
    _record(tmp_path, good, 5.0, 2, here)
    damaged = [
        [],
        {"kind": "collect", "wall_s": 5.0, "cost": {"key": "collect|x", "units": "1000"}},
        {"kind": "collect", "wall_s": 5.0, "cost": {"units": 1000}},
        {"kind": "collect", "wall_s": 5.0, "threads": "two", "cost": {"key": "k", "units": 1}},
        {"kind": "collect", "wall_s": "5", "cost": {"key": "k", "units": 1}},
        {"kind": "collect", "wall_s": 5.0, "cpu": 3, "cost": {"key": "k", "units": 1}},
        {"kind": "collect", "wall_s": float("nan"), "cost": {"key": "k", "units": 1}},
        {"kind": "collect", "wall_s": 10**400, "cost": {"key": "k", "units": 1}},  # overflows
        {"kind": "collect", "wall_s": 5.0, "cost": {"key": "k", "units": 10**400}},
        {"kind": "collect", "wall_s": 5.0, "threads": -1, "cost": {"key": "k", "units": 1}},
        {"kind": "collect", "wall_s": 5.0, "threads": 10**300, "cost": {"key": "k", "units": 1}},
    ]
    for i, rec in enumerate(damaged):
        d = tmp_path / "collect" / f"bad{i}"
        d.mkdir()
        (d / DONE_FILE).write_text(json.dumps(rec))
    assert [r["label"] for r in measured_stages(tmp_path)] == ["g"]
    # a training whose own log holds a runtime too large for a float: its wall time is the rate
    t = Stage("train", "t", {"i": "t"}, _noop, cost=Cost("train|x", 100))
    _record(tmp_path, t, 20.0, 2, here)
    (t.path(tmp_path) / "model").mkdir()
    (t.path(tmp_path) / "model" / "training_log.json").write_text(
        json.dumps([{"train_runtime": 10**400}])
    )
    assert {r["label"]: r["work_s"] for r in measured_stages(tmp_path)}["t"] == 20.0
    # the same model name with another instruction set is another machine: not this one's rate
    other = Stage("collect", "o", {"i": "o"}, _noop, cost=Cost("collect|x", 1000))
    _record(tmp_path, other, 500.0, 2, here)
    rec = json.loads((other.path(tmp_path) / DONE_FILE).read_text())
    (other.path(tmp_path) / DONE_FILE).write_text(json.dumps({**rec, "isa": isa + "-other"}))
    n = Stage("collect", "n", {"i": "n"}, _noop, cost=Cost("collect|x", 1000))
    est = estimate([n], tmp_path, reference={"cpu": "?", "rates": []})
    assert est["stages"][0]["seconds"] == pytest.approx(5.0)  # the good stage's rate alone
    text = render(est, "head")
    assert "1 of 1 stage to run" in text and "(here, 1 stage)" in text
    # a stage finished here records the instruction set
    from lhf_hf.reproduce.stages import StageRunner

    fresh = Stage("filter", "f", {"i": "f"}, lambda out: time.sleep(0.15), cost=Cost("filter", 10))
    StageRunner(tmp_path, echo=lambda m: None).run(fresh)
    assert json.loads((fresh.path(tmp_path) / DONE_FILE).read_text())["isa"] == isa


def test_durations_read_at_a_glance():
    from lhf_hf.reproduce.estimate import duration

    assert duration(45) == "45 s"
    assert duration(600) == "10.0 min"
    assert duration(5399) == "1.5 h" and duration(5370) == "89.5 min"  # never "90.0 min"
    assert duration(7200) == "2.0 h"
    assert duration(47 * 3600) == "47.0 h"
    assert duration(3000 * 3600) == "125.0 days"  # the paper preset on 2 cores


def test_the_work_folder_must_be_a_folder(tmp_path):
    from lhf_hf.reproduce import estimate_experiment, export_experiment, reproduce

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


def test_twins_lend_their_rates_and_say_so():
    """A Meta-World task never measured takes another ML1 task's rate (one model size, one
    simulator), named in the basis; gridworlds of other sizes or contexts lend nothing."""
    from lhf_hf.reproduce.estimate import find_twin_rate, twins

    assert "metaworld-reach-wall" in twins("metaworld-reach")
    assert "metaworld-reach" not in twins("metaworld-reach")
    assert twins("darkroom") == []  # darkroom-permuted: another context; -large: another grid
    # gridworld variants declare no cost class: Key-to-Door's planned steps cost 1.4x Permuted's,
    # though their spaces, horizon and context are one
    assert twins("darkroom-permuted") == [] and twins("dark-key-to-door") == []
    ref = {"cpu": "cpu A", "rates": [
        {"key": "train|metaworld-reach-wall|dicp|paper|window|ctx500", "threads": 1,
         "seconds_per_unit": 2e-5, "overhead_s": 3.0, "stages": 2},
    ]}  # fmt: skip
    key = "train|metaworld-push|dicp|paper|window|ctx500"
    assert find_rate(key, 1, {}, "cpu A", ref) is None
    rate = find_twin_rate(key, 1, {}, "cpu A", ref)
    assert (rate.seconds_per_unit, rate.overhead_s, rate.stages) == (2e-5, 3.0, 2)
    assert rate.basis == "reference, measured on metaworld-reach-wall"
    # another context is another rate; keys without an env, or of an unknown env, have no twin
    assert find_twin_rate(key.replace("ctx500", "ctx200"), 1, {}, "cpu A", ref) is None
    assert find_twin_rate("filter", 1, {}, "cpu A", ref) is None
    assert find_twin_rate("train|no-such-env|ad", 1, {}, "cpu A", ref) is None


def test_older_records_are_re_keyed_by_the_context_they_ran_at(tmp_path):
    """Records made before keys named a non-default context: a training's context comes from its
    config, an evaluation's from its training's record; one that cannot be told is no rate (not
    a rate filed under the default context: Meta-World's 1,000 against the 500 it ran at)."""
    here = cpu_model()
    mw = "metaworld-reach-wall"
    old_train = Stage("train", "t", {"context_length": 500}, _noop,
                      cost=Cost(f"train|{mw}|dicp|paper|window", 100))  # fmt: skip
    default_train = Stage("train", "d", {"context_length": None}, _noop,
                          cost=Cost(f"train|{mw}|ad|paper|window", 100))  # fmt: skip
    _record(tmp_path, old_train, 20.0, 1, here)
    _record(tmp_path, default_train, 20.0, 1, here)
    ev = Stage("evaluate", "e", {"model": old_train.hash}, _noop,
               cost=Cost(f"evaluate|{mw}|dicp|paper|plan|window", 50))  # fmt: skip
    orphan = Stage("evaluate", "o", {"model": "f" * 64}, _noop,
                   cost=Cost(f"evaluate|{mw}|ad|paper|no plan|window", 50))  # fmt: skip
    grid = Stage("evaluate", "g", {"model": "e" * 64}, _noop,
                 cost=Cost("evaluate|darkroom|ad|paper|no plan|window", 50))  # fmt: skip
    for s in (ev, orphan, grid):
        _record(tmp_path, s, 5.0, 1, here)
    keys = {r["label"]: r["cost"]["key"] for r in measured_stages(tmp_path)}
    assert keys == {
        "t": f"train|{mw}|dicp|paper|window|ctx500",
        "d": f"train|{mw}|ad|paper|window",  # its env's default: untagged, as now
        "e": f"evaluate|{mw}|dicp|paper|plan|window|ctx500",
        # "o": its training's record is not here, so its context is unknown: no rate
        # "g": likewise, whatever its env
    }
    # an imported training's record (stage.record.json) tells its evaluations' context too
    (tmp_path / "train" / "ffffffffffff").mkdir()
    (tmp_path / "train" / "ffffffffffff" / RECORD_FILE).write_text(
        json.dumps({"kind": "train", "config": {"context_length": 200}})
    )
    keys = {r["label"]: r["cost"]["key"] for r in measured_stages(tmp_path)}
    assert keys["o"] == f"evaluate|{mw}|ad|paper|no plan|window|ctx200"


def test_new_records_are_keyed_as_made(tmp_path):
    """A record of the current format keeps its key: no lookup of its training is needed."""
    from lhf_hf.reproduce.stages import StageRunner

    def work(out):
        time.sleep(0.15)

    ev = Stage("evaluate", "e", {"model": "f" * 64}, work,
               cost=Cost("evaluate|darkroom|ad|paper|no plan|window", 50))  # fmt: skip
    StageRunner(tmp_path, echo=lambda m: None).run(ev)
    rec = json.loads((ev.path(tmp_path) / DONE_FILE).read_text())
    assert rec["cost"] == {
        "key": "evaluate|darkroom|ad|paper|no plan|window",
        "units": 50,
        "format": COST_FORMAT,
    }
    assert [r["cost"]["key"] for r in measured_stages(tmp_path)] == [rec["cost"]["key"]]


def test_a_key_without_a_rate_says_which_contexts_were_measured():
    """Meta-World at its default context 1,000 (the paper preset) has no rate: the reason names
    the 500 its own and its twins' stages ran at, rather than only a raw key."""
    from lhf_hf.reproduce.estimate import _other_contexts

    known = {"train|metaworld-reach-wall|ad|paper|window|ctx500", "train|darkroom|ad|paper|window"}
    assert _other_contexts("train|metaworld-reach|ad|paper|window", known) == (
        " (measured only at context 500: a rate holds for one context)"
    )
    assert _other_contexts("train|metaworld-reach|dicp|paper|window", known) == ""  # other model
    assert _other_contexts("train|darkroom|ad|paper|window|ctx40", known) == (
        " (measured only at the env's default context: a rate holds for one context)"
    )
    assert _other_contexts("collect|darkroom|batched|ppo", known) == ""
