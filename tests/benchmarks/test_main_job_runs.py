"""benchmarks/validation/main_job_runs.py: the chance the paired t-test reads "helps", and the
main job's runs and rollouts."""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "validation" / "main_job_runs.py"
_spec = importlib.util.spec_from_file_location("main_job_runs", SCRIPT)
_module = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_module)


@pytest.mark.parametrize(
    ("effect", "n", "want"),
    # the paired t-test's two-sided power at 5 % (G*Power; pwr::pwr.t.test(d, n, type="paired"))
    # less its lower tail, which is below 0.001 for these effects; with no effect, 2.5 %
    [(1.0, 5, 0.401), (0.5, 34, 0.808), (1.0, 10, 0.803), (0.0, 6, 0.025)],
)
def test_helps_is_the_paired_t_tests_upper_rejection(effect, n, want):
    assert _module.helps(effect, 1.0, n) == pytest.approx(want, abs=0.002)


def test_far_tails_and_no_spread_are_certain_not_nan():
    assert _module.helps(10.0, 0.3, 8) == 1.0
    assert _module.helps(-10.0, 0.3, 8) == 0.0
    assert _module.helps(1.0, 0.0, 3) == 1.0 and _module.helps(-1.0, 0.0, 3) == 0.0


def _record(folder: Path, baseline, lhf, rollouts: int = 4, tasks: str = "validation") -> Path:
    from lhf_hf.evaluation.compare import paired_statistics

    row = {"baseline_run_means": baseline, "lhf_run_means": lhf, **paired_statistics(
        np.array(baseline), np.array(lhf))}  # fmt: skip
    folder.mkdir()
    evaluate = {"rollouts": rollouts, "tasks": tasks}
    record = {"experiment": {"evaluate": evaluate}, "cells": [{"rows": [row]}]}
    (folder / "results.json").write_text(json.dumps(record))
    return folder


def _run(monkeypatch, *args) -> dict:
    out = args[args.index("--out") + 1]
    monkeypatch.setattr(sys, "argv", [str(SCRIPT), *map(str, args)])
    _module.main()
    return json.loads((Path(out) / "runs.json").read_text())


def test_each_rollout_count_pools_its_cpus_and_the_fastest_agreeing_budget_is_chosen(
    tmp_path, monkeypatch
):
    # 4 rollouts: differences +1, +3 and +2, +2, +2 (two CPUs; pooled mean 2, variance
    # (2 + 0) / (1 + 2) = 2/3); 16 rollouts: +2, +2.2 and +1.8, +2 (mean 2, variance
    # (0.02 + 0.02) / 2 = 0.02)
    a = _record(tmp_path / "a", [1.0, 1.0], [2.0, 4.0])
    b = _record(tmp_path / "b", [1.0, 2.0, 3.0], [3.0, 4.0, 5.0])
    c = _record(tmp_path / "c", [1.0, 1.0], [3.0, 3.2], rollouts=16)
    d = _record(tmp_path / "d", [1.0, 1.0], [2.8, 3.0], rollouts=16)
    result = _run(monkeypatch, a, b, c, d, "--run-seconds", "4=100", "16=120", "--budget", 500,
                  "--out", tmp_path / "out")  # fmt: skip
    assert result["spread"]["4"]["mu"] == pytest.approx(2.0)
    assert result["spread"]["4"]["sigma"] == pytest.approx((2 / 3) ** 0.5)
    assert result["spread"]["16"]["sigma"] == pytest.approx(0.02**0.5)
    by = {(t["rollouts"], t["runs"]): t for t in result["table"]}
    assert [n for (r, n), t in by.items() if r == 4 and t["fits"]] == [3, 4, 5]
    assert [n for (r, n), t in by.items() if r == 16 and t["fits"]] == [3, 4]
    for (r, n), t in by.items():
        s = result["spread"][str(r)]
        assert t["helps"] == pytest.approx(_module.helps(s["mu"], s["sigma"], n))
        assert t["both_help"] == pytest.approx(t["helps"] ** 2)
    # 4 rollouts first reach 0.9 at 5 runs (500 s), 16 at 3 (360 s): the faster is chosen
    assert [n for (r, n), t in by.items() if r == 4 and t["both_help"] >= 0.9][0] == 5
    assert by[(16, 3)]["both_help"] >= 0.9
    assert result["chosen"] == {"rollouts": 16, "runs": 3}
    assert [r["verdict"] for r in result["records"]][1] == "helps"
    md = (tmp_path / "out" / "runs.md").read_text()
    assert "| b | 4 | 3 | +2.00, +2.00, +2.00 |" in md


def test_without_enough_power_the_budget_most_likely_to_help_on_both(tmp_path, monkeypatch):
    a = _record(tmp_path / "a", [1.0, 1.0, 1.0], [1.0, 3.0, 1.5])  # mean +0.83, std 1.04
    result = _run(monkeypatch, a, "--run-seconds", "4=100", "--budget", 400, "--out", tmp_path)
    fits = [t for t in result["table"] if t["fits"]]
    assert all(t["both_help"] < 0.9 for t in fits)
    assert result["chosen"] == {"rollouts": 4, "runs": 4}  # the most runs the budget holds


def test_no_effect_is_never_chosen_as_agreement(tmp_path, monkeypatch):
    # two CPUs that would both read "no clear effect" agree, but that is not what is asked: a
    # budget that cannot show the effect must not pass (mean +0.05, std ~0.8)
    a = _record(tmp_path / "a", [1.0, 1.0, 1.0, 1.0], [2.0, 0.2, 1.0, 1.0])
    b = _record(tmp_path / "b", [1.0, 1.0, 1.0, 1.0], [1.1, 1.1, 0.2, 1.8])
    result = _run(monkeypatch, a, b, "--run-seconds", "4=50", "--budget", 600, "--out", tmp_path)
    assert all(t["both_help"] < 0.1 for t in result["table"])
    assert result["chosen"] == {"rollouts": 4, "runs": 10}


def test_bad_input_is_refused(tmp_path, monkeypatch):
    missing = tmp_path / "missing"
    with pytest.raises(SystemExit, match="missing/results.json: cannot be read"):
        _run(monkeypatch, missing, "--run-seconds", "4=1", "--out", tmp_path)
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "results.json").write_text("{}")
    with pytest.raises(SystemExit, match="not a main-job validation record"):
        _run(monkeypatch, tmp_path / "empty", "--run-seconds", "4=1", "--out", tmp_path)
    test = _record(tmp_path / "test", [1.0, 1.0], [2.0, 4.0], tasks="test")
    with pytest.raises(SystemExit, match="not on validation goals"):
        _run(monkeypatch, test, "--run-seconds", "4=1", "--out", tmp_path)
    a = _record(tmp_path / "a", [1.0, 1.0], [2.0, 4.0], rollouts=16)
    with pytest.raises(SystemExit, match="no wall time for \\[16\\] rollouts"):
        _run(monkeypatch, a, "--run-seconds", "4=1", "--out", tmp_path)
    for bad in ("16", "16=-3", "16=nan"):
        with pytest.raises(SystemExit, match="--run-seconds"):
            _run(monkeypatch, a, "--run-seconds", bad, "--out", tmp_path)
    with pytest.raises(SystemExit, match="named twice"):
        _run(monkeypatch, a, a, "--run-seconds", "16=1", "--out", tmp_path)
    with pytest.raises(SystemExit, match="a file, not a folder"):
        _run(monkeypatch, a, "--run-seconds", "16=1", "--out", a / "results.json")
