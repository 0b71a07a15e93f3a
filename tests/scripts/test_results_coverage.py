"""Coverage: which cells of a shipped spec a results folder holds at the preset's current budget,
and what is left of the rest (committed exports counted as done)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lhf_hf.configs import EvalConfig
from lhf_hf.reproduce.experiment import load_experiment
from lhf_hf.reproduce.reproduce import plan_stages
from tests.scripts import load_script

module = load_script("results_coverage")
coverage, differences = module.coverage, module.differences
recorded_experiment, render_coverage = module.recorded_experiment, module.render_coverage
named, PLAN_TIES_SINCE = module.named, module.PLAN_TIES_SINCE
render_index = load_script("results_index").render_index


def _table(root: Path, folder: str, exp: dict, rows: list[dict], created: str, stage_s=3600.0):
    (root / folder).mkdir(parents=True)
    summary = {
        "experiment": exp,
        "cells": [{"env_id": "darkroom", "arm": arm, "rows": [r]} for arm, r in rows],
        "stage_s": stage_s,
        "created": created,
    }
    (root / folder / "results.json").write_text(json.dumps(summary))
    (root / folder / "report.md").write_text("# report")


def _row(backbone: str, e: float) -> dict:
    return {"backbone": backbone, "E": e, "E_std": 0.1, "baseline_mean": 10.0, "lhf_mean": 11.0}


def test_differences_are_of_each_cell_s_own_settings_defaults_filled_in():
    exp = load_experiment("darkroom-main", "cpu")
    now = json.loads(json.dumps(exp.to_dict()))

    def diff(rec: dict, obj: str) -> list[str]:
        return differences(recorded_experiment({"experiment": rec}, exp), exp, "darkroom", obj)

    assert diff(now, "ad") == [] and diff(now, "dicp") == []
    old = json.loads(json.dumps(now))
    old["collect"]["histories"] = 50
    old["train"]["max_steps"] = 1000  # AD's and DPT's steps; DICP keeps its own override (4,000)
    assert diff(old, "ad") == ["collect.histories 50 (now 100)", "train.max_steps 1000 (now 3000)"]
    assert diff(old, "dicp") == ["collect.histories 50 (now 100)"]
    del old["train"]["by_objective"]  # DICP then trained for the shared 1,000 steps
    assert "train.max_steps 1000 (now 4000)" in diff(old, "dicp")
    # the planner's settings date DICP's cells only; a default written out is no difference
    gate = json.loads(json.dumps(now))  # a table whose every planned evaluation was gated
    gate["evaluate"].update(plan_dicp="both", plan_gate="reward_seen")
    gate["evaluate"]["episodes"] = EvalConfig(model="-", out="-").episodes
    assert diff(gate, "ad") == [] and diff(gate, "dpt") == []
    assert diff(gate, "dicp") == ["evaluate.plan.plan_gate reward_seen (now always)"]
    # a mode or an arm only one side has is one entry; the derived chunk size written out is none
    once = json.loads(json.dumps(now))
    once["evaluate"]["plan_dicp"] = True
    once["collect"]["tasks_per_chunk"] = 500  # what 100 histories give anyway
    assert diff(once, "dicp") == ["evaluate.policy absent (now run)"] and diff(once, "ad") == []
    # a table made before the planner's reference tie order planned with ties by policy: its
    # planned cells are dated and its planned rows named so; its model-free ones stay current
    made = {"experiment": now, "created": "2026-12-02T00:00:00+0000"}
    old_ties = recorded_experiment(made, exp)
    assert differences(old_ties, exp, "darkroom", "dicp") == [
        "evaluate.plan.plan_ties policy (now index)",
    ] and differences(old_ties, exp, "darkroom", "ad") == []  # fmt: skip
    row = {"backbone": "DICP + plan"}
    assert named(row, made, "darkroom")["backbone"] == "DICP + plan, ties by policy"
    assert named({"backbone": "DICP"}, made, "darkroom")["backbone"] == "DICP"
    assert named(row, {**made, "created": PLAN_TIES_SINCE}, "darkroom")["backbone"] == "DICP + plan"
    # Meta-World plans with the greedy search: no tie order to name, no cell dated by it
    assert named(row, made, "metaworld-reach-wall")["backbone"] == "DICP + plan"
    # before the reference's depth-0 order as well: argmax order, named and dated
    older = {"experiment": now, "created": "2026-11-22T00:00:00+0000"}
    assert named(row, older, "darkroom")["backbone"] == "DICP + plan, argmax order, ties by policy"
    assert differences(recorded_experiment(older, exp), exp, "darkroom", "dicp") == [
        "evaluate.plan.plan_order argmax (now sample)",
        "evaluate.plan.plan_ties policy (now index)",
    ]
    assert named(row, older, "metaworld-reach-wall")["backbone"] == "DICP + plan"
    lam = load_experiment("darkroom-lambda", "cpu")
    fewer = json.loads(json.dumps(lam.to_dict()))
    fewer["filter"]["sweep"]["values"] = [0, 0.5, 1, 2]
    rec = recorded_experiment({"experiment": fewer}, lam)
    assert differences(rec, lam, "darkroom", "ad") == ["filter.lam=1000 absent (now run)"]


def test_cells_done_older_or_not_run_and_exported_runs_shorten_what_is_left(tmp_path):
    exp = load_experiment("darkroom-lambda", "cpu")
    now = exp.to_dict()
    older = json.loads(json.dumps(now))
    older["collect"]["histories"] = 50
    ad = [("lam=0", _row("AD", -0.062)), ("lam=1", _row("AD", 0.017))]
    # the current budget wins over a later table of an older one; two runs are not enough
    _table(tmp_path, "lam-ad", now, ad, "2027-01-01T00:00:00+0000", stage_s=8748)
    _table(tmp_path, "lam-ad-old", older, ad, "2027-01-02T00:00:00+0000")
    _table(tmp_path, "lam-ad-2runs", {**now, "runs": 2}, ad, "2027-01-03T00:00:00+0000")
    plan = [("lam=0", _row("DICP", 0.3)), ("lam=0", _row("DICP + plan", 0.25))]
    _table(tmp_path, "lam-dicp-old", older, plan, "2027-01-01T00:00:00+0000")
    before = coverage(tmp_path, "cpu", ["darkroom-lambda"])["specs"][0]
    (cell_ad, cell_dicp) = before["cells"]
    assert before["outside"] == []  # the lambda sweep is a Darkroom spec
    assert cell_ad["status"] == "done" and cell_ad["table"] == "lam-ad"
    assert [r["arm"] for r in cell_ad["rows"]] == ["lam=0", "lam=1"] and "left" not in cell_ad
    assert cell_dicp["status"] == "other settings" and cell_dicp["table"] == "lam-dicp-old"
    assert cell_dicp["differences"] == ["collect.histories 50 (now 100)"]
    assert cell_dicp["left"]["exported_runs"] == [] and cell_dicp["left"]["missing"] == []
    assert cell_dicp["left"]["wall_s"] > 0

    # run 0's DICP evaluations committed as an export: that run's trainings are not left
    stages, evals = plan_stages(exp, tmp_path / "nowhere")
    run0 = [
        s
        for (env, arm, obj), group in evals.items()
        if obj == "dicp"
        for s in group
        if s.config["seed"] == 0
    ]
    assert len(run0) == 6  # the baseline and 5 lambdas, one evaluation each
    (tmp_path / "stages" / "dicp-run0").mkdir(parents=True)
    index = {"stages": [{"kind": "evaluate", "hash": s.hash} for s in run0]}
    (tmp_path / "stages" / "dicp-run0" / "stages.json").write_text(json.dumps(index))
    cov = coverage(tmp_path, "cpu", ["darkroom-lambda"])
    after = cov["specs"][0]["cells"][1]["left"]
    assert after["exported_runs"] == [0] and after["exports"] == ["dicp-run0"]
    trainings = [s for s in stages if s.kind == "train" and "DICP" in s.label]
    assert len(trainings) == 3 * 6
    # a third of the trainings (and evaluations) fewer: about a third less wall time
    assert 0.55 < after["wall_s"] / cell_dicp["left"]["wall_s"] < 0.8

    text = "\n".join(render_coverage(cov))
    assert (
        "| darkroom-lambda | darkroom | AD | - | done | AD lam=0 -6.2, AD lam=1 +1.7 "
        "| [lam-ad](lam-ad/report.md) (2.43 h) | - |" in text
    )
    assert (
        "| darkroom-lambda | darkroom | DICP | - | other settings: collect.histories 50 (now 100) "
        in text
    )
    assert (
        "| DICP + plan lam=0 +25.0, DICP lam=0 +30.0 |" not in text
    )  # rows keep the table's order
    assert "DICP lam=0 +30.0, DICP + plan lam=0 +25.0" in text
    assert "; run 0 exported in dicp-run0 |" in text
    assert "1 of 2 cells done at the cpu preset's current settings; the other 1: ~" in text


def test_envs_outside_the_preset_and_unmeasured_stages_are_said(tmp_path, monkeypatch):
    shipped = module.reference()
    # the shipped rates without the SAC collection's (measured by sac-collection.yaml)
    no_sac = {k: r for k, r in shipped.items() if "|sac" not in k}
    monkeypatch.setattr(module, "reference", lambda: no_sac)
    cov = coverage(tmp_path, "cpu", ["darkroom-main", "metaworld-sac"])
    main, sac = cov["specs"]
    assert [c["env"] for c in main["cells"]] == ["darkroom"] * 3
    assert [c["status"] for c in main["cells"]] == ["not run"] * 3
    assert [o["env"] for o in main["outside"]] == [
        "darkroom-permuted",
        "darkroom-large",
        "dark-key-to-door",
    ]
    large = main["outside"][1]["left"]
    assert large["missing"] == [] and large["wall_s"] > 3600  # paper-size models, context 200
    text = "\n".join(render_coverage(cov))
    assert "- darkroom-main: darkroom-large, ~" in text
    assert "3 of the other 7: ~" in text and "; 4 of unknown cost." in text
    with pytest.raises(ValueError, match="unknown preset 'CPU'"):
        coverage(tmp_path, "CPU")
    # a collection never measured: no number pretends otherwise (the training and evaluation are
    # Meta-World Reach-Wall's, a twin env of the same sizes)
    assert (
        "| metaworld-sac | metaworld-push | AD | +33.5 | not run | - | - | unknown: never measured "
        "(collect sb3 sac) |" in text
    )
    # with the shipped rates every cell has an estimate: Push's SAC collection is Reach's
    monkeypatch.setattr(module, "reference", lambda: shipped)
    text = "\n".join(render_coverage(coverage(tmp_path, "cpu", ["metaworld-sac"])))
    assert "| metaworld-sac | metaworld-push | AD | +33.5 | not run | - | - | ~" in text
    assert "unknown: never measured" not in text


def test_the_index_lists_the_coverage_first_when_asked(tmp_path):
    assert "## Coverage" not in render_index(tmp_path)[0]
    text = render_index(tmp_path, coverage="quick")[0]
    assert text.index("## Coverage at the quick preset") < text.index("No tables yet")
    assert "| darkroom-main | darkroom | AD | +25.1 | not run |" in text


@pytest.mark.slow
def test_fewer_runs_and_malformed_tables_or_exports_are_named_never_fatal(tmp_path):
    exp = load_experiment("darkroom-lambda", "cpu")
    now = exp.to_dict()
    ad = [("lam=0", _row("AD", 0.1))]
    _table(tmp_path, "one-run", {**now, "runs": 1}, ad, "2027-01-01T00:00:00+0000")
    bad = {
        "runs-text": ({**now, "runs": "three"}, ad),
        "train-text": ({**now, "train": "abc"}, ad),
        "by-objective": ({**now, "train": {**now["train"], "by_objective": {"ad": "x"}}}, ad),
        "e-text": (now, [("lam=0", {**_row("AD", 0.1), "E": "0.5"})]),  # a string: no number
    }
    for name, (rec, rows) in bad.items():
        _table(tmp_path, name, rec, rows, "2027-01-02T00:00:00+0000", stage_s=float("nan"))
    (tmp_path / "cells-dict").mkdir()
    (tmp_path / "cells-dict" / "results.json").write_text(
        json.dumps({"experiment": now, "cells": {"x": 1}})
    )
    (tmp_path / "garbage").mkdir()
    (tmp_path / "garbage" / "results.json").write_text("{not json")
    (tmp_path / "stages" / "broken").mkdir(parents=True)
    (tmp_path / "stages" / "broken" / "stages.json").write_text('{"stages": [{"hash": "x"}]}')
    cov = coverage(tmp_path, "cpu", ["darkroom-lambda"])
    cell = cov["specs"][0]["cells"][0]
    # E "0.5" is no number, but the table is otherwise current: it is the newest done one
    assert (cell["status"], cell["table"], cell["rows"][0]["E"]) == ("done", "e-text", None)
    assert cell["stage_s"] is None  # NaN stage time: not shown
    named = " ".join(cov["malformed"])
    for name in ("runs-text", "train-text", "by-objective", "cells-dict", "garbage"):
        assert name in named
    (unread,) = cov["unread_exports"]
    assert unread.startswith("broken (") and "'kind'" in unread
    (tmp_path / "stages" / "empty").mkdir()  # a folder without an index is named too
    unread = coverage(tmp_path, "cpu", ["darkroom-lambda"])["unread_exports"]
    assert unread[0] == "empty (no stages.json)" and unread[1].startswith("broken (")
    text = "\n".join(render_coverage(cov))
    assert "| done | AD lam=0 - | [e-text](e-text/report.md) | - |" in text
    # the index and the coverage agree on what they cannot read: both name it, the script exits 2
    _, bad_index = render_index(tmp_path, coverage="cpu")
    for name in ("runs-text", "train-text", "by-objective", "cells-dict", "garbage"):
        assert name in bad_index
    assert "Exports not counted (their `stages.json` cannot be read): broken (" in text
    # without the good table, the one-run table is the newest at the current settings
    for name in bad:  # e-text among them
        (tmp_path / name / "results.json").unlink()
    cell = coverage(tmp_path, "cpu", ["darkroom-lambda"])["specs"][0]["cells"][0]
    assert (cell["status"], cell["runs"], cell["table"]) == ("fewer runs", 1, "one-run")
    assert "| fewer runs (1 of 3) |" in "\n".join(
        render_coverage(coverage(tmp_path, "cpu", ["darkroom-lambda"]))
    )


def test_a_custom_spec_of_a_shipped_stem_is_not_the_shipped_table(tmp_path):
    """``mine/darkroom-lambda.yaml`` shares the shipped spec's name (its stem), not its cells."""
    now = load_experiment("darkroom-lambda", "cpu").to_dict()
    ad = [("lam=0", _row("AD", 0.1))]
    _table(tmp_path, "custom", {**now, "spec": "mine/darkroom-lambda.yaml"}, ad, "2027-01-02")
    cell = coverage(tmp_path, "cpu", ["darkroom-lambda"])["specs"][0]["cells"][0]
    assert cell["status"] == "not run"
    _table(tmp_path, "shipped", now, ad, "2027-01-01")  # its own record names it by its name
    cell = coverage(tmp_path, "cpu", ["darkroom-lambda"])["specs"][0]["cells"][0]
    assert (cell["status"], cell["table"]) == ("done", "shipped")


@pytest.mark.parametrize(
    "v, number",
    [(0, True), (1.5, True), (-2, True), (True, False), ("3", False), (float("nan"), False),
     (float("inf"), False), (10**400, False), (None, False)],
)  # fmt: skip
def test_recorded_numbers_are_finite_json_numbers(v, number):
    assert module.recorded_number(v) == (float(v) if number else None)
