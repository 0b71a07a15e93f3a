"""benchmarks/reference_rates.py: this machine's rates table from finished stages, merged or not."""

import importlib.util
import json
import sys
from pathlib import Path

import pytest

from lhf_hf.collection.backend_verdict import cpu_model
from lhf_hf.reproduce.stages import DONE_FILE, config_hash

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "reference_rates.py"
_spec = importlib.util.spec_from_file_location("reference_rates", SCRIPT)
_module = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_module)
merge_rates = _module.merge_rates


def test_merge_weighs_by_units_else_by_stages_and_keeps_the_rest():
    old = [{"key": "a", "seconds_per_unit": 1.0, "units": 100.0, "stages": 1},
           {"key": "b", "seconds_per_unit": 5.0, "stages": 1}]  # fmt: skip
    new = [{"key": "a", "seconds_per_unit": 2.0, "units": 300.0, "stages": 2},
           {"key": "b", "seconds_per_unit": 2.0, "units": 10.0, "stages": 2},
           {"key": "c", "seconds_per_unit": 3.0, "units": 1.0, "stages": 1}]  # fmt: skip
    a, b, c = merge_rates(old, new)
    assert (a["seconds_per_unit"], a["units"], a["stages"]) == (1.75, 400.0, 3)
    assert b["seconds_per_unit"] == 3.0 and "units" not in b  # by stages: 5 x 1 + 2 x 2
    assert c == new[2]


def _run(tmp_path, out, *extra):
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(
            sys, "argv", ["reference_rates.py", str(tmp_path / "work"), "--out", str(out), *extra]
        )
        _module.main()


def _stage(tmp_path, i: int, key: str, wall: float, units: float, cpu=None) -> None:
    config = {"i": i}
    stage = tmp_path / "work" / "collect" / config_hash({"kind": "collect", **config})[:12]
    stage.mkdir(parents=True)
    record = {"kind": "collect", "config": config, "wall_s": wall, "cpu": cpu or cpu_model(),
              "cost": {"key": key, "units": units}}  # fmt: skip
    (stage / DONE_FILE).write_text(json.dumps(record))


def test_this_machine_s_table_is_written_in_place_and_merged(tmp_path):
    _stage(tmp_path, 0, "collect|darkroom|batched|ppo", 10.0, 1000.0)
    _stage(tmp_path, 1, "collect|darkroom|batched|ppo", 30.0, 1000.0)
    _stage(tmp_path, 2, "collect|darkroom|batched|ppo", 99.0, 1.0, cpu="another CPU")  # not ours
    out = tmp_path / "rates.json"
    other = {"cpu": "first", "rates": [{"key": "k", "seconds_per_unit": 1.0, "stages": 1}]}
    mine = {"cpu": cpu_model(), "command": "old", "rates": [
        {"key": "collect|darkroom|batched|ppo", "seconds_per_unit": 0.1, "units": 2000.0, "stages": 1}]}  # fmt: skip
    out.write_text(json.dumps({"machines": [other, mine]}))
    _run(tmp_path, out)
    first, table = json.loads(out.read_text())["machines"]
    assert first == other and table["cpu"] == cpu_model()  # the first machine stays first
    assert table["rates"] == [{"key": "collect|darkroom|batched|ppo", "seconds_per_unit": 0.02,
                               "units": 2000.0, "stages": 2}]  # fmt: skip
    out.write_text(json.dumps({"machines": [other, mine]}))
    _run(tmp_path, out, "--merge")
    (rate,) = json.loads(out.read_text())["machines"][1]["rates"]
    assert rate["seconds_per_unit"] == pytest.approx(0.06) and rate["stages"] == 3
    kept = {"key": "train|darkroom|ad|paper|window", "seconds_per_unit": 7.0, "stages": 1}
    mine["rates"].append(kept)
    out.write_text(json.dumps({"machines": [other, mine]}))
    _run(tmp_path, out, "--replace")  # the measured key replaced, not pooled; the other kept
    table = json.loads(out.read_text())["machines"][1]
    assert table["rates"] == [
        {"key": "collect|darkroom|batched|ppo", "seconds_per_unit": 0.02, "units": 2000.0,
         "stages": 2},
        kept,
    ]  # fmt: skip
    assert table["command"].startswith("old; then ") and table["command"].endswith("--replace")
    # --only: the keys matching a pattern (none here: nothing to write, the table untouched)
    before = out.read_text()
    with pytest.raises(SystemExit, match=r"matching \['train\|\*'\]"):
        _run(tmp_path, out, "--replace", "--only", "train|*")
    assert out.read_text() == before
    _run(tmp_path, out, "--replace", "--only", "collect|*")
    assert json.loads(out.read_text())["machines"][1]["command"].endswith(
        "--only 'collect|*' --replace"
    )


@pytest.mark.parametrize(
    "text", ["{bad", "{}", "[]", "null", '{"machines": 5}', '{"machines": [1]}']
)
@pytest.mark.slow
def test_a_malformed_rates_file_is_refused_and_left_as_it_was(tmp_path, text):
    _stage(tmp_path, 0, "collect|darkroom|batched|ppo", 10.0, 1000.0)
    out = tmp_path / "rates.json"
    out.write_text(text)
    with pytest.raises(SystemExit, match="not a rates table"):
        _run(tmp_path, out, "--merge")
    assert out.read_text() == text
    (tmp_path / "work2").write_text("a file")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sys, "argv", ["reference_rates.py", str(tmp_path / "work2")])
        with pytest.raises(SystemExit, match="not a stage cache folder"):
            _module.main()
