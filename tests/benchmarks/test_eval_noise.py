"""benchmarks/eval_noise.py: rollout noise against model noise, hand-computed."""

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "eval_noise.py"
_spec = importlib.util.spec_from_file_location("eval_noise", SCRIPT)
_module = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_module)


def _record(*models):
    runs = [{"points": [{"step": 10, "whole_curve": list(m)}]} for m in models]
    return {"objectives": {"ad": {"tasks": [1, 2], "runs": runs}}}


def test_rollout_and_model_noise_split_as_computed_by_hand():
    # models [1, 3] and [5, 7]: each seed variance 2; the means 2 and 6 vary by 8 (ddof 1), of
    # which 2 / 2 seeds is rollout noise, so the models differ by 7
    (row,) = _module.noise(_record([1, 3], [5, 7]))
    assert (row["models"], row["seeds"], row["mean_return"]) == (2, 2, 4.0)
    assert row["rollout_std"] == pytest.approx(2**0.5)
    assert row["model_std"] == pytest.approx(7**0.5)
    assert row["std_of_R"][1] == pytest.approx(3.0)
    assert row["std_of_R"][4] == pytest.approx(7.5**0.5)


def test_model_noise_floors_at_zero_and_one_seed_is_refused():
    (row,) = _module.noise(_record([1, 3], [1.5, 2.5]))  # means 2 and 2: all rollout noise
    assert row["model_std"] == 0.0
    with pytest.raises(SystemExit, match="one evaluation seed"):
        _module.noise(_record([1.0], [2.0]))
