"""benchmarks/reference_rates.py --merge: a calibration added to an older table."""

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "reference_rates.py"
_spec = importlib.util.spec_from_file_location("reference_rates", SCRIPT)
_module = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_module)
merge_rates = _module.merge_rates


def _rate(key, threads, spu, overhead, stages):
    return {
        "key": key,
        "threads": threads,
        "seconds_per_unit": spu,
        "overhead_s": overhead,
        "stages": stages,
    }


def test_merge_pools_shared_keys_by_stage_count_and_keeps_the_rest():
    old = [
        _rate("filter", 2, 1.0e-6, 0.0, 5),
        _rate("train|darkroom|ad|paper|window", 1, 4e-5, 0.7, 2),
    ]
    new = [
        _rate("filter", 2, 4.0e-6, 0.6, 1),
        _rate("train|metaworld-reach-wall|ad|paper|window", 1, 3e-4, 1.0, 2),
    ]
    got = {(r["key"], r["threads"]): r for r in merge_rates(old, new)}
    assert sorted(got) == [
        ("filter", 0),  # a filter's rate does not depend on torch's threads
        ("train|darkroom|ad|paper|window", 1),
        ("train|metaworld-reach-wall|ad|paper|window", 1),
    ]
    # (5 x 1e-6 + 1 x 4e-6) / 6 = 1.5e-6; (5 x 0 + 1 x 0.6) / 6 = 0.1
    assert got["filter", 0]["seconds_per_unit"] == pytest.approx(1.5e-6)
    assert got["filter", 0]["overhead_s"] == pytest.approx(0.1)
    assert got["filter", 0]["stages"] == 6
    assert got["train|darkroom|ad|paper|window", 1] == old[1]
    assert got["train|metaworld-reach-wall|ad|paper|window", 1] == new[1]
    assert old[0]["stages"] == 5  # the inputs are not changed


def test_merge_weighs_rates_by_their_units_when_both_record_them():
    # Meta-World Reach-Wall's SB3 collection: a calibration stage of 8,000 transitions in 12.7 s
    # (mostly start-up) and a table's 1,000,000 in 355.1 s
    old = [{**_rate("collect|metaworld-reach-wall|sb3|ppo", 0, 12.7 / 8000, 0.0, 1), "units": 8e3}]
    new = [{**_rate("collect|metaworld-reach-wall|sb3|ppo", 0, 355.1 / 1e6, 0.0, 1), "units": 1e6}]
    (r,) = merge_rates(old, new)
    # (12.7 + 355.1) / 1,008,000 s per transition, the table's collection within 4 %
    assert r["seconds_per_unit"] == pytest.approx(367.8 / 1.008e6)
    assert (r["units"], r["stages"]) == (1.008e6, 2)
    # one side without units: weighed by stages, and the pooled rate no longer claims units
    (r,) = merge_rates(
        [_rate("filter", 0, 1.0, 0.0, 1)], [{**_rate("filter", 0, 3.0, 0.0, 3), "units": 9.0}]
    )
    assert r["seconds_per_unit"] == pytest.approx((1.0 + 9.0) / 4) and "units" not in r


def test_merge_reads_a_missing_start_up_as_zero():
    old = [{k: v for k, v in _rate("filter", 0, 1.0, 0.0, 1).items() if k != "overhead_s"}]
    (r,) = merge_rates(old, [_rate("filter", 0, 3.0, 0.8, 3)])
    assert r["overhead_s"] == pytest.approx(0.6) and r["stages"] == 4


def test_merge_keeps_thread_counts_apart():
    old = [_rate("evaluate|darkroom|ad|paper|no plan|window", 1, 3e-4, 0.4, 2)]
    new = [_rate("evaluate|darkroom|ad|paper|no plan|window", 2, 2e-4, 0.4, 2)]
    assert [r["threads"] for r in merge_rates(old, new)] == [1, 2]


def test_a_malformed_rates_file_is_refused_and_left_as_it_was(tmp_path):
    import json
    import subprocess
    import sys

    from lhf_hf.collection.backend_verdict import cpu_model
    from lhf_hf.reproduce.stages import DONE_FILE, config_hash

    config = {"i": "abc"}  # a finished stage's folder is named by its config's hash
    stage = tmp_path / "work" / "collect" / config_hash({"kind": "collect", **config})[:12]
    stage.mkdir(parents=True)
    record = {
        "kind": "collect",
        "config": config,
        "wall_s": 10.0,
        "cpu": cpu_model(),
        "threads": 2,
        "cost": {"key": "collect|darkroom|batched|ppo", "units": 1000.0},
    }
    (stage / DONE_FILE).write_text(json.dumps(record))
    malformed = (
        "{bad",
        '{"machines": [{"cpu": "x"}]}',
        "{}",  # valid JSON, no table: once silently replaced
        "[]",
        "5",
        "null",
        '{"machines": 5}',
        '{"machines": [1]}',
        '{"rates": [1]}',
        '{"machines": [{"cpu": "x", "rates": [{"key": "k", "seconds_per_unit": 1, "stages": 1}]}]}',
        '{"machines": [{"rates": [{"key": "k", "threads": "two", "seconds_per_unit": 1, "stages": 1}]}]}',
        '{"machines": [{"rates": [{"key": "k", "threads": 1, "seconds_per_unit": -1, "stages": 1}]}]}',
        '{"kind": "report", "cells": []}',  # another lhf output (results.json)
        '{"rates": [{"key": "k", "threads": 1, "seconds_per_unit": 1, "stages": 1, "units": 1'
        + "0" * 400
        + "}]}",  # an integer too large for a float
        '{"command": 5, "rates": []}',
        '{"date": ["x"], "rates": []}',
    )

    def refusal(out, *extra):
        # in-process (each subprocess would import torch): SystemExit with a message is what a
        # user sees as one line
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(
                sys,
                "argv",
                ["reference_rates.py", str(tmp_path / "work"), "--out", str(out), *extra],
            )
            with pytest.raises(SystemExit) as e:
                _module.main()
        return str(e.value.code)

    for text in malformed:
        out = tmp_path / "rates.json"
        out.write_text(text)
        assert "not a rates table" in refusal(out, "--merge"), text
        assert out.read_text() == text
    assert "not a file" in refusal(tmp_path)  # a folder as --out
    # a WORK that is empty, a file or missing: refused (an empty name would scan this folder)
    out.write_text("{}")
    for work in ("", str(out), str(tmp_path / "missing")):
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(sys, "argv", ["reference_rates.py", work, "--out", str(tmp_path / "n.json")])
            with pytest.raises(SystemExit) as e:
                _module.main()
        assert "not a stage cache folder" in str(e.value.code)
    assert not (tmp_path / "n.json").exists()
    # the command line: a one-line refusal, no traceback, the file unchanged
    out.write_text("{}")
    run = subprocess.run(
        [sys.executable, str(SCRIPT), str(tmp_path / "work"), "--out", str(out)],
        capture_output=True,
        text=True,
    )
    assert run.returncode != 0 and "not a rates table" in run.stderr, run.stderr
    assert "Traceback" not in run.stderr and out.read_text() == "{}"


def test_merge_pools_a_collection_filed_under_two_thread_counts():
    old = [_rate("collect|darkroom|batched|ppo", 2, 1e-5, 0.0, 3)]
    new = [_rate("collect|darkroom|batched|ppo", 1, 2e-5, 0.0, 1)]
    (r,) = merge_rates(old, new)
    # (3 x 1e-5 + 1 x 2e-5) / 4
    assert (r["threads"], r["stages"]) == (0, 4)
    assert r["seconds_per_unit"] == pytest.approx(1.25e-5)


def _collect_stage(work, wall):
    import json

    from lhf_hf.collection.backend_verdict import cpu_model
    from lhf_hf.reproduce.stages import DONE_FILE, config_hash

    config = {"wall": wall}  # a finished stage's folder is named by its config's hash
    stage = work / "collect" / config_hash({"kind": "collect", **config})[:12]
    stage.mkdir(parents=True)
    record = {
        "kind": "collect",
        "config": config,
        "wall_s": wall,
        "cpu": cpu_model(),
        "threads": 2,
        "cost": {"key": "collect|darkroom|batched|ppo", "units": 1000.0},
    }
    (stage / DONE_FILE).write_text(json.dumps(record))


def test_merge_adds_to_the_table_of_this_cpu_model_and_instruction_set_only(tmp_path):
    import json
    import subprocess
    import sys

    from lhf_hf.collection.backend_verdict import cpu_model, instruction_set

    cpu, isa = cpu_model(), instruction_set()
    _collect_stage(tmp_path / "work", 10.0)  # 0.01 s per transition
    other_isa = {"cpu": cpu, "isa": isa + "-other", "date": "2026-01-01", "rates": [
        _rate("collect|darkroom|batched|ppo", 0, 0.5, 0.0, 9)]}  # fmt: skip
    mine = {"cpu": cpu, "isa": isa, "machine": "m", "date": "2026-01-02", "command": "c",
            "rates": [_rate("collect|darkroom|batched|ppo", 2, 0.03, 0.0, 1)]}  # fmt: skip
    out = tmp_path / "rates.json"
    out.write_text(json.dumps({"machines": [other_isa, mine]}))
    run = subprocess.run(
        [sys.executable, str(SCRIPT), str(tmp_path / "work"), "--out", str(out), "--merge"],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr
    first, second = json.loads(out.read_text())["machines"]
    assert first == other_isa  # the same model name with another instruction set: not pooled
    (r,) = second["rates"]
    # the shipped rate records no units: weighed by stages
    assert r["seconds_per_unit"] == pytest.approx((0.03 + 0.01) / 2) and r["threads"] == 0
    assert second["isa"] == isa and second["command"].startswith("c; then ")
    # when each part was measured
    assert second["date"].startswith("2026-01-02, merged ")


def test_two_tables_of_this_machine_pool_into_one(tmp_path):
    import json
    import subprocess
    import sys

    from lhf_hf.collection.backend_verdict import cpu_model, instruction_set

    cpu, isa = cpu_model(), instruction_set()
    _collect_stage(tmp_path / "work", 10.0)  # 0.01 s per transition
    other = {"cpu": "Other CPU", "isa": "avx2", "rates": [_rate("filter", 0, 1.0, 0.0, 1)]}
    # one written before tables recorded the instruction set, one after: both this machine's
    no_isa = {"cpu": cpu, "date": "2026-01-01", "command": "a",
              "rates": [_rate("collect|darkroom|batched|ppo", 0, 0.02, 0.0, 1)]}  # fmt: skip
    # (a rate without its start-up: optional, printed as 0)
    no_start = {k: v for k, v in _rate("train|darkroom|ad|paper|window", 1, 4e-5, 0, 2).items()
                if k != "overhead_s"}  # fmt: skip
    with_isa = {"cpu": cpu, "isa": isa, "date": "2026-01-02", "command": "b", "rates": [no_start]}
    out = tmp_path / "rates.json"
    out.write_text(json.dumps({"machines": [other, no_isa, with_isa]}))
    run = subprocess.run(
        [sys.executable, str(SCRIPT), str(tmp_path / "work"), "--out", str(out), "--merge"],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr
    assert "2 tables of this machine" in run.stdout
    assert "(1 stage)" in run.stdout or "(2 stages)" in run.stdout
    machines = json.loads(out.read_text())["machines"]
    assert len(machines) == 2 and machines[0] == other  # the first stays first
    got = {r["key"]: r for r in machines[1]["rates"]}
    # nothing of either table lost: the second's training rate kept, the collection pooled
    assert got["train|darkroom|ad|paper|window"]["seconds_per_unit"] == 4e-5
    assert got["collect|darkroom|batched|ppo"]["seconds_per_unit"] == pytest.approx(0.015)
    assert got["collect|darkroom|batched|ppo"]["stages"] == 2
    assert machines[1]["command"].startswith("a; b; then ")
    assert machines[1]["date"].startswith("2026-01-01, 2026-01-02, merged ")
    # without --merge: this machine's new table replaces both
    out.write_text(json.dumps({"machines": [other, no_isa, with_isa]}))
    run = subprocess.run(
        [sys.executable, str(SCRIPT), str(tmp_path / "work"), "--out", str(out)],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr
    assert "replacing this machine's 2 rates" in run.stdout
    machines = json.loads(out.read_text())["machines"]
    assert len(machines) == 2 and [r["key"] for r in machines[1]["rates"]] == [
        "collect|darkroom|batched|ppo"
    ]
