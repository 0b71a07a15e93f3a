"""benchmarks/validation/state_encoding.py: two encodings' evaluations compared within goals, and
the rule that keeps a departure only where it is ahead by more than the margin."""

import importlib.util
import json
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "validation" / "state_encoding.py"
_spec = importlib.util.spec_from_file_location("state_encoding", SCRIPT)
_module = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_module)


def _eval(folder: Path, per_goal: list[list[float]], tasks=(2, 35, 42), data="fp-a") -> None:
    """An ``eval_results.json`` with 2 rollouts of 2 episodes per goal; ``per_goal[r][i]`` is
    goal i's return in both episodes of rollout r (rows rollout-major, as ``lhf evaluate``)."""
    returns = [[v, v] for rollout in per_goal for v in rollout]
    folder.mkdir(parents=True)
    folder.joinpath("eval_results.json").write_text(json.dumps({
        "tasks": list(tasks), "rollouts": len(per_goal), "returns": returns,
        "model": {"dataset": {"fingerprint": data}}}))  # fmt: skip


def test_within_goal_difference_and_the_rule(tmp_path):
    # ours: goal means 2, 4, 6 (policy), the reference's: 3, 4, 8 -> differences +1, 0, +2
    _eval(tmp_path / "ours-policy", [[1, 4, 5], [3, 4, 7]])
    _eval(tmp_path / "ref-policy", [[3, 3, 8], [3, 5, 8]])
    # planned: ours 5, 5, 5 against 2, 2, 2 -> ours ahead by 3 on every goal
    _eval(tmp_path / "ours-ref", [[5, 5, 5], [5, 5, 5]])
    _eval(tmp_path / "ref-ref", [[2, 2, 2], [2, 2, 2]])
    prefixes = [str(tmp_path / "ours"), str(tmp_path / "ref")]
    found = _module.compare(prefixes, ["coordinates", "cells"], ["policy", "ref"], 0.98)
    policy, planned = found["rows"]
    assert (policy["coordinates"], policy["cells"]) == (pytest.approx(4.0), pytest.approx(5.0))
    assert policy["diff"] == pytest.approx(1.0)
    # t(0.975, 2) = 4.303, std of (1, 0, 2) = 1: half-width 4.303 / sqrt(3) = 2.484
    assert policy["ci95"] == pytest.approx([1 - 2.484, 1 + 2.484], abs=1e-3)
    assert (policy["goals_up"], policy["goals"]) == (2, 3)
    assert planned["diff"] == pytest.approx(-3.0) and planned["goals_up"] == 0
    assert found["choice"] == "coordinates" and found["same_data"]  # ahead by 3 > 0.98 planned
    # ahead by less than the margin everywhere: the reference's encoding
    found = _module.compare(prefixes, ["coordinates", "cells"], ["policy", "ref"], 3.5)
    assert found["choice"] == "cells"
    assert "Choice: **cells**" in _module.render(found)


def test_other_goals_are_refused_and_other_data_is_said(tmp_path):
    _eval(tmp_path / "a-policy", [[1, 2, 3]], data="x")
    _eval(tmp_path / "b-policy", [[1, 2, 3]], tasks=(2, 35, 44))
    with pytest.raises(SystemExit, match="other goals"):
        _module.compare([str(tmp_path / "a"), str(tmp_path / "b")], ["a", "b"], ["policy"], 1.0)
    _eval(tmp_path / "c-policy", [[1, 2, 4]], data="y")
    found = _module.compare([str(tmp_path / "a"), str(tmp_path / "c")], ["a", "b"], ["policy"], 1.0)
    assert not found["same_data"] and "two draws" in _module.render(found)
