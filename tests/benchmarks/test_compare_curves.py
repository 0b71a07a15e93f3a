"""benchmarks/compare_curves.py: curve records against the first, hand-computed."""

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "compare_curves.py"
_spec = importlib.util.spec_from_file_location("compare_curves", SCRIPT)
_module = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_module)


def _record(*models):
    """One point per model at step 10: (whole_curve seeds, last10 seeds)."""
    runs = [{"points": [{"step": 10, "whole_curve": w, "last10": t}]} for w, t in models]
    return {"objectives": {"ad": {"runs": runs}}}


def test_each_record_against_the_first_over_model_means():
    ref = _record(([1, 3], [0, 2]), ([3, 5], [2, 4]))  # model means 2 and 4 (last 10: 1, 3)
    other = _record(([4, 6], [1, 3]), ([6, 8], [3, 5]))  # 5 and 7 (2, 4)
    rows = _module.compare({"ref": ref, "other": other})
    whole = [r for r in rows if r["metric"] == "whole_curve"]
    assert [(r["record"], r["mean"], r["difference"]) for r in whole] == [
        ("ref", 3.0, None), ("other", 6.0, 3.0)]  # fmt: skip
    assert whole[1]["std"] == pytest.approx(2**0.5) and whole[0]["welch_p"] is None
    # equal spreads, difference 3 over a standard error of sqrt(2 / 2 + 2 / 2): t = 2.12, 2 dof
    assert whole[1]["welch_p"] == pytest.approx(0.168, abs=1e-3)
    last = [r for r in rows if r["metric"] == "last10" and r["record"] == "other"]
    assert last[0]["difference"] == 1.0
