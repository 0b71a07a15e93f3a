"""lhf reproduce --export-stages / --import-stages: a table finished on two machines.

Machine A runs run 0 of a two-run table and exports; machine B (another work folder) imports and
runs only what is left: run 1 whole, and run 0's collection and filter (the report reads the
selection), but not run 0's trainings, whose evaluations came with the import.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from lhf_hf.cli.main import main
from lhf_hf.reproduce import estimate_experiment, export_experiment, load_experiment, reproduce
from lhf_hf.reproduce.parallel import run_stages
from lhf_hf.reproduce.portable import INDEX_FILE, import_stages
from lhf_hf.reproduce.reproduce import plan_stages
from lhf_hf.reproduce.stages import DONE_FILE, RECORD_FILE, Stage, StageRunner, needed_stages
from lhf_hf.utils.outputs import OutputError
from tests.reproduce.test_reproduce import TINY, _spec


def _kind(stage_entry: dict) -> str:
    return Path(stage_entry["path"]).parent.name


@pytest.mark.slow
def test_a_table_finished_on_a_second_machine_from_the_first_ones_evaluations(tmp_path, capsys):
    spec = _spec(tmp_path, TINY)
    work_a, work_b = tmp_path / "a", tmp_path / "b"
    reproduce(spec, "quick", runs=1, out=tmp_path / "out_a", work=work_a, echo=lambda s: None)
    carried = tmp_path / "carried"
    n = export_experiment(spec, carried, "quick", runs=2, work=work_a)
    # run 0's 2 evaluations whole; records of its collection, filter and 2 trainings; run 1 not done
    assert n == {"portable": 2, "records": 4, "not_done": 6}
    index = json.loads((carried / INDEX_FILE).read_text())
    assert index["experiment"] == "tiny" and index["runs"] == 2
    assert not list(carried.rglob("*.safetensors")) and not list(carried.rglob("*.parquet"))
    assert not list(carried.rglob("stage.log"))

    # what is left, estimated after the import: 2 + 6 stages (run 0's trainings left out)
    text = estimate_experiment(spec, "quick", 2, work_b, import_from=[carried], echo=print)
    assert "imported from" in capsys.readouterr().out
    assert "8 of 10 stages to run" in text

    lines: list[str] = []
    reproduce(
        spec, "quick", 2, tmp_path / "out_b", work_b, echo=lines.append, import_from=[carried]
    )
    assert any("0 evaluation(s), 4 record(s), 2 already here" in s for s in lines)  # 2nd import
    summary = json.loads((tmp_path / "out_b" / "results.json").read_text())
    ran = sorted(_kind(s) for s in summary["stages"] if not s["cached"])
    assert ran == ["collect", "collect", "evaluate", "evaluate", "filter", "filter"] + ["train"] * 2
    assert sorted(_kind(s) for s in summary["stages"] if s["cached"]) == ["evaluate"] * 2
    exp = load_experiment(spec, "quick", 2)
    stages, evals = plan_stages(exp, work_b)
    run0_trains = [s for s in stages if s.kind == "train" and "run 0" in s.label]
    for tr in run0_trains:  # never trained here: only the imported record of what it cost
        assert not tr.done(work_b) and (tr.path(work_b) / RECORD_FILE).exists()
        assert not (tr.path(work_b) / "model").exists()
    # run 0's evaluations are A's, byte for byte, and the report reads them
    for ev in [s for s in stages if s.kind == "evaluate" and "run 0" in s.label]:
        ours = (ev.path(work_b) / "eval" / "eval_results.json").read_bytes()
        assert ours == (ev.path(work_a) / "eval" / "eval_results.json").read_bytes()
    row = summary["cells"][0]["rows"][0]
    assert row["runs_baseline"] == row["runs_lhf"] == 2
    # the table's cost counts run 0's trainings from their records, as if they had run here
    recorded = sum(json.loads(p.read_text())["wall_s"] for p in work_b.glob("*/*/stage.json"))
    records = sum(  # of the stages that did not run here (here, the stage's own time counts)
        json.loads(p.read_text())["wall_s"]
        for p in work_b.glob(f"*/*/{RECORD_FILE}")
        if not (p.parent / DONE_FILE).exists()
    )
    assert records > 0
    assert summary["stage_s"] == pytest.approx(recorded + records, abs=0.2)
    # the recollected run 0 selects what A's did (one seed reaches every RNG)
    sel_a = json.loads((tmp_path / "out_a" / "results.json").read_text())["selections"][0]
    assert summary["selections"][0] == sel_a


def test_import_errors_and_a_foreign_export(tmp_path):
    spec = _spec(tmp_path, TINY)
    exp = load_experiment(spec, "quick", 2)
    work = tmp_path / "w"
    plan, _ = plan_stages(exp, work)
    with pytest.raises(ValueError, match="is not an export of finished stages"):
        import_stages(tmp_path, work, plan)
    # an export whose evaluation was edited after it was made
    ev = next(s for s in plan if s.kind == "evaluate")
    src = tmp_path / "exp"
    (src / "evaluate" / ev.hash[:12] / "eval").mkdir(parents=True)
    done = {"kind": "evaluate", "label": ev.label, "config": ev.config, "wall_s": 1.0}
    (src / "evaluate" / ev.hash[:12] / DONE_FILE).write_text(json.dumps(done))
    entry = {
        "kind": "evaluate",
        "label": ev.label,
        "hash": ev.hash,
        "path": f"evaluate/{ev.hash[:12]}",
    }
    (src / INDEX_FILE).write_text(json.dumps({"format": 1, "stages": [entry]}))
    assert import_stages(src, work, plan)["imported"] == 1 and ev.done(work)
    assert import_stages(src, work, plan)["present"] == 1  # a second import changes nothing
    done["config"] = {**ev.config, "episodes": 999}
    (src / "evaluate" / ev.hash[:12] / DONE_FILE).write_text(json.dumps(done))
    with pytest.raises(ValueError, match="does not match its recorded config"):
        import_stages(src, tmp_path / "w2", plan)
    (src / INDEX_FILE).write_text(json.dumps({"format": 7, "stages": []}))
    with pytest.raises(ValueError, match="format 7, this version reads 1"):
        import_stages(src, work, plan)
    # an export of another plan: nothing of it is in this one, and the import says so
    from lhf_hf.reproduce.reproduce import _import

    lines: list[str] = []
    done["config"] = ev.config
    (src / "evaluate" / ev.hash[:12] / DONE_FILE).write_text(json.dumps(done))
    (src / INDEX_FILE).write_text(json.dumps({"format": 1, "stages": [entry]}))
    _import([src], tmp_path / "w3", [Stage("evaluate", "x", {"z": 1}, print)], lines.append)
    assert "warning: none of" in lines[-1]


def test_export_refuses_a_foreign_folder_and_the_cli_checks_its_flags(tmp_path, capsys):
    spec = _spec(tmp_path, TINY)
    mine = tmp_path / "notes"
    mine.mkdir()
    (mine / "todo.txt").write_text("mine")
    with pytest.raises(OutputError):
        export_experiment(spec, mine, "quick", work=tmp_path / "w")
    assert (mine / "todo.txt").read_text() == "mine"
    out = tmp_path / "carried"
    assert (
        main(["reproduce", spec, "--work", str(tmp_path / "w"), "--export-stages", str(out)]) == 0
    )
    assert "exported to" in capsys.readouterr().out
    assert json.loads((out / INDEX_FILE).read_text())["stages"] == []  # nothing done yet
    assert main(["reproduce", spec, "--export-stages", str(out), "--estimate"]) == 1
    assert "export_stages runs nothing else" in capsys.readouterr().err
    assert main(["reproduce", spec, "--work", str(tmp_path / "w"), "--estimate",
                 "--import-stages", str(tmp_path)]) == 1  # fmt: skip
    assert "is not an export of finished stages" in capsys.readouterr().err


def _noop(out: Path) -> None:
    (out / DONE_FILE).write_text("{}")


def test_needed_stages_leave_out_what_only_done_stages_read(tmp_path):
    col = Stage("collect", "collect", {"i": 0}, _noop)
    fil = Stage("filter", "filter", {"i": 1}, _noop, (col,))
    tr = Stage("train", "train", {"i": 2}, _noop, (col, fil))
    ev = Stage("evaluate", "eval", {"i": 3}, _noop, (tr,))
    plan = [col, fil, tr, ev]
    assert needed_stages(plan, tmp_path, [fil, ev]) == plan  # nothing done: everything
    ev.path(tmp_path).mkdir(parents=True)
    _noop(ev.path(tmp_path))  # the evaluation came with an import
    assert needed_stages(plan, tmp_path, [fil, ev]) == [col, fil, ev]  # no training
    assert needed_stages(plan, tmp_path, [ev]) == [ev]  # nor a collection nobody reads
    # with two jobs the done evaluation is reported cached although its training is not planned
    runner = StageRunner(tmp_path, total=3, echo=lambda s: None)
    command = lambda s: [sys.executable, "-c", "raise SystemExit(3)"]  # noqa: E731
    run_stages([col, fil, ev], runner, jobs=2, worker_command=command)
    assert [e["cached"] for e in runner.log] == [False, False, True]
    assert col.done(tmp_path) and fil.done(tmp_path) and not tr.done(tmp_path)
