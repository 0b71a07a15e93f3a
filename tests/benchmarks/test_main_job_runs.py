"""benchmarks/validation/main_job_runs.py: the paired t-test's power and the main job's runs."""

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
    # two-sided paired t at 5 %, effect size mu / sigma: the textbook values (G*Power, and
    # pwr::pwr.t.test(d, n, type="paired") gives the same)
    [(1.0, 5, 0.401), (0.5, 34, 0.808), (1.0, 10, 0.803), (0.0, 6, 0.05)],
)
def test_power_is_the_paired_t_tests(effect, n, want):
    assert _module.power(effect, 1.0, n) == pytest.approx(want, abs=0.002)


def test_power_far_in_the_tail_is_one_not_nan():
    assert _module.power(10.0, 0.3, 8) == 1.0
    assert _module.power(-10.0, 0.3, 8) == pytest.approx(1.0)


def _record(folder: Path, baseline, lhf) -> Path:
    from lhf_hf.evaluation.compare import paired_statistics

    row = {"baseline_run_means": baseline, "lhf_run_means": lhf, **paired_statistics(
        np.array(baseline), np.array(lhf))}  # fmt: skip
    folder.mkdir()
    (folder / "results.json").write_text(json.dumps({"cells": [{"rows": [row]}]}))
    return folder


def _run(monkeypatch, *args) -> None:
    monkeypatch.setattr(sys, "argv", [str(SCRIPT), *map(str, args)])
    _module.main()


def test_the_fewest_runs_whose_two_draws_agree_within_the_budget(tmp_path, monkeypatch):
    # differences +1, +3 and +2, +2, +2 (pooled: mean 2, variance (2 + 0) / (1 + 2) = 2/3)
    a = _record(tmp_path / "a", [1.0, 1.0], [2.0, 4.0])
    b = _record(tmp_path / "b", [1.0, 2.0, 3.0], [3.0, 4.0, 5.0])
    _run(monkeypatch, a, b, "--power-from", a, b, "--run-seconds", 100, "--budget", 500,
         "--out", tmp_path / "out")  # fmt: skip
    result = json.loads((tmp_path / "out" / "runs.json").read_text())
    assert result["mu"] == pytest.approx(2.0)
    assert result["sigma"] == pytest.approx((2 / 3) ** 0.5)
    by_runs = {t["runs"]: t for t in result["table"]}
    assert [n for n, t in by_runs.items() if t["fits"]] == [3, 4, 5]
    for t in result["table"]:
        assert t["power"] == pytest.approx(_module.power(2.0, (2 / 3) ** 0.5, t["runs"]))
        assert t["agreement"] == pytest.approx(t["power"] ** 2 + (1 - t["power"]) ** 2)
    first = min(n for n, t in by_runs.items() if t["fits"] and t["agreement"] >= 0.9)
    assert result["chosen_runs"] == first
    assert [r["verdict"] for r in result["records"]][1] == "helps"
    assert "| b | 3 | +2.00, +2.00, +2.00 |" in (tmp_path / "out" / "runs.md").read_text()


def test_without_enough_power_the_most_runs_the_budget_holds(tmp_path, monkeypatch):
    a = _record(tmp_path / "a", [1.0, 1.0, 1.0], [1.0, 3.0, 1.5])  # mean +0.83, std 1.04
    _run(
        monkeypatch, a, "--power-from", a, "--run-seconds", 100, "--budget", 400, "--out", tmp_path
    )
    result = json.loads((tmp_path / "runs.json").read_text())
    assert result["chosen_runs"] == 4
    assert all(t["agreement"] < 0.9 for t in result["table"] if t["fits"])


def test_a_folder_that_is_not_a_record_is_refused(tmp_path, monkeypatch):
    with pytest.raises(SystemExit, match="not a main-job validation record"):
        _run(monkeypatch, tmp_path, "--power-from", tmp_path, "--run-seconds", 1, "--out", tmp_path)
