"""benchmarks/bench_icrl_curve.py: flags checked before any training, the output policy of every
lhf command (never someone's files, never the dataset), and a run that resumes from its record."""

from __future__ import annotations

import importlib.util
import json
import shlex
import shutil
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_icrl_curve.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_icrl_curve", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture()
def data(learned_darkroom, tmp_path):
    """Goals 3 and 40: train goals of split 0, so its test goals are unseen."""
    root = tmp_path / "data"
    shutil.copytree(learned_darkroom.root, root)
    return root


def _run(bench, monkeypatch, *argv):
    monkeypatch.setattr(sys, "argv", ["bench_icrl_curve.py", *map(str, argv)])
    bench.main()


TINY = ["--objectives", "ad", "--preset", "tiny", "--batch-size", "2", "--episodes", "1"]


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--steps", "2", "--minutes", "1"], "not with --steps"),
        (["--steps", "2", "--every", "1"], "not with --steps"),
        (["--steps", "4", "--every-steps", "3"], "must divide"),
        (["--every-steps", "2"], "goes with --steps"),
        (["--steps", "2", "--episodes", "0"], "--episodes >= 1"),
        (["--steps", "2", "--plan"], "add dicp"),
        (["--steps", "2", "--plan-gate", "reward_seen"], "add --plan"),
    ],
)
def test_contradicting_flags_are_errors_before_any_work(
    bench, monkeypatch, tmp_path, flags, message
):
    with pytest.raises(SystemExit, match=message):
        _run(bench, monkeypatch, "--dataset", tmp_path / "none", *TINY, *flags,
             "--out", tmp_path / "out", "--work", tmp_path / "work")  # fmt: skip
    assert not (tmp_path / "out").exists() and not (tmp_path / "work").exists()


@pytest.mark.slow
def test_bad_inputs_are_one_line_errors_and_nothing_is_written(bench, monkeypatch, data, tmp_path):
    common = [*TINY, "--steps", "2"]
    with pytest.raises(SystemExit, match="no dataset at"):
        _run(bench, monkeypatch, "--dataset", tmp_path / "none", *common, "--out", tmp_path / "o")
    with pytest.raises(SystemExit, match="lr"):
        _run(bench, monkeypatch, "--dataset", data, *common, "--lr", "-1", "--out", tmp_path / "o")
    # someone's folder: refused before training, their files untouched
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "curve.png").write_bytes(b"mine")
    with pytest.raises(SystemExit, match="not an lhf icrl-curve"):
        _run(bench, monkeypatch, "--dataset", data, *common, "--out", victim,
             "--work", tmp_path / "work")  # fmt: skip
    assert (victim / "curve.png").read_bytes() == b"mine"
    # the dataset itself, as --out or as --work
    with pytest.raises(SystemExit, match="is the input"):
        _run(bench, monkeypatch, "--dataset", data, *common, "--out", data)
    with pytest.raises(SystemExit, match="inside the dataset"):
        _run(bench, monkeypatch, "--dataset", data, *common, "--out", tmp_path / "o",
             "--work", data / "ckpt")  # fmt: skip
    # a file as --out: refused before a model is trained for it
    with pytest.raises(SystemExit, match="is a file"):
        _run(bench, monkeypatch, "--dataset", data, *common, "--out", victim / "curve.png",
             "--work", tmp_path / "work")  # fmt: skip
    assert not (tmp_path / "o").exists()
    assert not any((tmp_path / "work").glob("*")) if (tmp_path / "work").exists() else True


@pytest.mark.slow
def test_a_wall_clock_run_records_a_command_that_resumes(bench, monkeypatch, data, tmp_path):
    out, work = tmp_path / "curve", tmp_path / "work"
    flags = [*TINY, "--minutes", "0.01", "--every", "0.01", "--seeds", "0",
             "--dataset", data, "--out", out, "--work", work]  # fmt: skip
    _run(bench, monkeypatch, *flags)
    record = json.loads((out / "curve.json").read_text())
    assert "None" not in record["command"]  # every flag parses back (issue: --steps None)
    assert "--steps" not in shlex.split(record["command"])
    assert record["env_id"] == "darkroom" and record["levels"]["ad"] == 12.5
    (run,) = record["objectives"]["ad"]["runs"]
    assert run["train_seed"] == 0 and run["points"]
    assert (out / "curve.png").exists()
    # --resume with the same settings trains nothing and keeps the record
    _run(bench, monkeypatch, *flags, "--resume")
    assert json.loads((out / "curve.json").read_text())["objectives"] == record["objectives"]
    # other settings: named, in the flags' own spelling
    with pytest.raises(SystemExit, match=r"--seeds 0 \(now --seeds 0 1\)"):
        _run(bench, monkeypatch, *flags, "--seeds", "0", "1", "--resume")
    # without --resume the record is never overwritten
    with pytest.raises(SystemExit, match="pass --resume"):
        _run(bench, monkeypatch, *flags)


def test_data_holding_test_goals_is_refused(bench, monkeypatch, small_darkroom_batched, tmp_path):
    """The small dataset holds goal 62, a test goal of split 0: its curve would measure a
    trained-on goal as unseen, so the benchmark stops, as `lhf evaluate` does."""
    from lhf_hf.evaluation.seen import SeenTasksError

    with pytest.raises(SeenTasksError, match=r"\(62\)"):
        _run(bench, monkeypatch, "--dataset", small_darkroom_batched.root, "--steps", "2",
             "--work", tmp_path / "work", "--out", tmp_path / "out.json", *TINY,
             "--tasks", "test", "--report-on-test")  # fmt: skip


def test_test_goals_are_measured_only_to_report(bench, monkeypatch, data, tmp_path):
    """A tuning tool measures on validation goals; test goals only with --report-on-test,
    refused before any work."""
    with pytest.raises(SystemExit, match="test goals are for reporting only"):
        _run(bench, monkeypatch, "--dataset", data, "--steps", "2", "--tasks", "test",
             "--work", tmp_path / "work", "--out", tmp_path / "out", *TINY)  # fmt: skip
    assert not (tmp_path / "work").exists() and not (tmp_path / "out").exists()
