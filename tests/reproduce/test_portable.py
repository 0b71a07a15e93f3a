"""lhf reproduce --export-stages / --import-stages: a table finished on two machines.

Machine A runs run 0 of a two-run table and exports; machine B (another work folder) imports and
runs only what is left: run 1 whole, and run 0's collection and filter (the report reads the
selection), but not run 0's trainings, whose evaluations came with the import.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest

from lhf_hf.cli.main import main
from lhf_hf.reproduce import estimate_experiment, export_experiment, load_experiment, reproduce
from lhf_hf.reproduce.parallel import run_stages
from lhf_hf.reproduce.portable import INDEX_FILE, ExportError, import_stages
from lhf_hf.reproduce.reproduce import plan_stages
from lhf_hf.reproduce.stages import DONE_FILE, RECORD_FILE, Stage, StageRunner, needed_stages
from lhf_hf.utils.io import sha256_file
from lhf_hf.utils.outputs import OutputError, record_manifest
from lhf_hf.verify import verify
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
    assert n == {
        "portable": 2,
        "records": 4,
        "not_done": 6,
        "command": f"lhf reproduce {spec} --preset quick --runs 2 --import-stages {carried}",
    }
    # the CLI says how to finish the table elsewhere, as a line that runs as written
    assert main(["reproduce", spec, "--runs", "2", "--work", str(work_a), "--export-stages",
                 str(tmp_path / "cli")]) == 0  # fmt: skip
    command = n["command"].replace(str(carried), str(tmp_path / "cli"))
    assert f"Elsewhere: {command}\n" in capsys.readouterr().out
    index = json.loads((carried / INDEX_FILE).read_text())
    assert index["experiment"] == "tiny" and index["runs"] == 2
    assert not list(carried.rglob("*.safetensors")) and not list(carried.rglob("*.parquet"))
    assert not list(carried.rglob("stage.log"))

    # what is left, estimated after the import: 2 + 6 stages (run 0's trainings left out)
    text = estimate_experiment(spec, "quick", 2, work_b, import_from=[carried], echo=print)
    assert "imported from" in capsys.readouterr().out
    assert "8 of 10 stage(s) to run" in text
    # the header's plan counts 12 stages: it says the 2 not in the list and why
    assert "12 stages (2 left out: what reads them is done)" in text.splitlines()[0]

    lines: list[str] = []
    report = reproduce(
        spec, "quick", 2, tmp_path / "out_b", work_b, echo=lines.append, import_from=[carried]
    )
    assert any("0 evaluation(s), 0 record(s), 2 already here" in s for s in lines)  # 2nd import
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
    run0_evals = [s for s in stages if s.kind == "evaluate" and "run 0" in s.label]
    for ev in run0_evals:
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
    # the report names what was made elsewhere
    assert [i["stage"] for i in summary["imported"]] == [ev.label for ev in run0_evals]
    assert "2 evaluation(s) were imported (`--import-stages`)" in report.read_text()
    assert summary["left_out"] == 2 and "2 left out" in report.read_text()
    # exported on again, to a third machine: run 0's trainings go as the records they are here
    assert export_experiment(spec, tmp_path / "again", "quick", 2, work_b) == {
        "portable": 4,
        "records": 8,
        "not_done": 0,
        "command": f"lhf reproduce {spec} --preset quick --runs 2 --import-stages {tmp_path / 'again'}",
    }
    # the recollected run 0 selects what A's did (one seed reaches every RNG)
    sel_a = json.loads((tmp_path / "out_a" / "results.json").read_text())["selections"][0]
    assert summary["selections"][0] == sel_a
    assert summary["other_data"] == [] and "**Warning**" not in report.read_text()
    # ... which a machine of another instruction set would not: the imported models' dataset
    # (here edited into another draw) differs from the collection made here, and the report says
    # its selection summary is not of the data those models trained on
    for ev in run0_evals:
        path = ev.path(work_b) / "eval" / "eval_results.json"
        found = json.loads(path.read_text())
        found["model"]["dataset"]["fingerprint"] = "f" * 64
        path.write_text(json.dumps(found))
        record_manifest(path.parent, "evaluation")  # as if evaluate had written it so
    report = reproduce(spec, "quick", 2, tmp_path / "out_c", work_b, echo=lambda s: None)
    other = json.loads((tmp_path / "out_c" / "results.json").read_text())["other_data"]
    assert sorted(o["stage"] for o in other) == sorted(ev.label for ev in run0_evals)
    assert {o["trained_on"] for o in other} == {"f" * 64} and other[0]["here_machine"]["isa"]
    text = report.read_text()
    assert "**Warning**: 2 evaluation(s) are of models trained on another draw" in text
    assert f"- {run0_evals[0].label}: trained on ffffffffffff, here " in text
    assert set(other[0]["here_machine"]) == {"cpu", "isa", "threads"}  # no local paths
    # a fingerprint that is no string (edited to null) is nothing to compare, not a crash
    path = run0_evals[0].path(work_b) / "eval" / "eval_results.json"
    found = json.loads(path.read_text())
    found["model"]["dataset"]["fingerprint"] = None
    path.write_text(json.dumps(found))
    record_manifest(path.parent, "evaluation")
    reproduce(spec, "quick", 2, tmp_path / "out_c", work_b, echo=lambda s: None)
    other = json.loads((tmp_path / "out_c" / "results.json").read_text())["other_data"]
    assert [o["stage"] for o in other] == [run0_evals[1].label]


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """Run 0 of the tiny two-run table finished in work ``a`` and exported to ``carried``."""
    root = tmp_path_factory.mktemp("portable")
    spec = _spec(root, TINY)
    reproduce(spec, "quick", runs=1, out=root / "out", work=root / "a", echo=lambda s: None)
    export_experiment(spec, root / "carried", "quick", runs=2, work=root / "a")
    return spec, root


def _copy(root: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "copy"
    shutil.copytree(root / "carried", dst)
    return dst


@pytest.mark.slow
def test_an_edited_or_malformed_export_is_refused_whole(exported, tmp_path):
    spec, root = exported
    plan, _ = plan_stages(load_experiment(spec, "quick", 2), tmp_path)
    work = tmp_path / "w"
    for folder in (tmp_path / "nowhere", root):
        with pytest.raises(ExportError, match="is no readable export of finished stages"):
            import_stages(folder, work, plan)
    # returns edited after the export: the checksums say so, and nothing is copied
    src = _copy(root, tmp_path)
    index = json.loads((src / INDEX_FILE).read_text())
    second = index["stages"][-1]
    results = src / second["path"] / "eval" / "eval_results.json"
    results.write_text(results.read_text().replace('"mean_return": ', '"mean_return": 99 + '))
    with pytest.raises(ExportError, match="changed since it was exported"):
        import_stages(src, work, plan)
    assert verify(root / "carried")["problems"] == []
    assert any("changed since it was exported" in p for p in verify(src)["problems"])
    assert not work.exists()  # checked whole before the first copy
    # a config edited in stage.json and its checksum with it: the hash still tells
    shutil.rmtree(src)
    src = _copy(root, tmp_path)
    done_path = src / second["path"] / DONE_FILE
    done = json.loads(done_path.read_text())
    done["config"]["episodes"] = 999
    done_path.write_text(json.dumps(done))
    index["stages"][-1]["files"][DONE_FILE] = sha256_file(done_path)
    (src / INDEX_FILE).write_text(json.dumps(index))
    with pytest.raises(ExportError, match="does not match its recorded config"):
        import_stages(src, work, plan)
    # an entry that would read outside the export, or another format
    good = json.loads((root / "carried" / INDEX_FILE).read_text())
    for bad in (
        {**second, "path": "../../etc"},
        {**second, "hash": "../../../etc", "path": "evaluate/../../../etc"},
    ):
        (src / INDEX_FILE).write_text(json.dumps({**good, "stages": [bad]}))
        with pytest.raises(ExportError, match="changed since it was exported"):
            import_stages(src, work, plan)
    (src / INDEX_FILE).write_text(json.dumps({**good, "format": 7}))
    with pytest.raises(ExportError, match="format 7, this version reads 2"):
        import_stages(src, work, plan)
    # several folders: all checked before the first copy
    with pytest.raises(ExportError, match="format 7"):
        estimate_experiment(spec, "quick", 2, work, import_from=[root / "carried", src])
    assert not work.exists()


def test_imports_copy_only_this_plans_stages_once_and_say_what_matched(exported, tmp_path):
    spec, root = exported
    work = tmp_path / "w"
    plan, _ = plan_stages(load_experiment(spec, "quick", 2), work)
    n = import_stages(root / "carried", work, plan)
    assert (n["imported"], n["records"], n["present"], n["evaluations_in_plan"]) == (2, 4, 0, 2)
    again = import_stages(root / "carried", work, plan)  # a second import changes nothing
    assert (again["imported"], again["records"], again["present"]) == (0, 0, 2)
    imported = [s for s in plan if s.kind == "evaluate" and s.done(work)]
    origin = json.loads((imported[0].path(work) / DONE_FILE).read_text())["imported"]
    assert origin["from"] == str((root / "carried").resolve()) and origin["versions"]
    # an evaluation whose mark was edited into no record is not done: the import replaces it
    (imported[0].path(work) / DONE_FILE).write_text("[]")
    assert not imported[0].done(work)
    fixed = import_stages(root / "carried", work, plan)
    assert (fixed["imported"], fixed["present"]) == (1, 1) and imported[0].done(work)
    # another spec (one setting differs): nothing of the export is in its plan, nothing copied
    other = json.loads(json.dumps(TINY))
    other["presets"]["quick"]["evaluate"]["episodes"] = 3
    other_spec = _spec(tmp_path, other, "tiny")
    lines: list[str] = []
    estimate_experiment(other_spec, "quick", 2, tmp_path / "w2", import_from=[root / "carried"],
                        echo=lines.append)  # fmt: skip
    assert "0 of its 2 evaluation(s) are in this plan" in lines[0]
    assert "warning: none of" in lines[1] and "changed spec" in lines[1]
    assert not list((tmp_path / "w2").glob("evaluate/*"))
    assert (
        "exported from tiny --preset quick --runs 2, this is tiny --preset quick --runs 2"
        in lines[1]
    )


def test_export_refuses_what_it_would_lose_and_the_cli_checks_its_flags(exported, tmp_path, capsys):
    spec, root = exported
    mine = tmp_path / "notes"
    mine.mkdir()
    (mine / "todo.txt").write_text("mine")
    with pytest.raises(OutputError):
        export_experiment(spec, mine, "quick", runs=2, work=root / "a")
    assert (mine / "todo.txt").read_text() == "mine"
    with pytest.raises(ExportError, match="does not exist: nothing to export"):
        export_experiment(spec, tmp_path / "e", "quick", work=tmp_path / "typo")
    with pytest.raises(ExportError, match="inside the work folder"):
        export_experiment(spec, root / "a" / "e", "quick", work=root / "a")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ExportError, match="no evaluation of this plan is finished"):
        export_experiment(spec, tmp_path / "e", "quick", work=tmp_path / "empty")
    # a good export is not replaced by one that lacks an evaluation of it
    carried = _copy(root, tmp_path)
    less = tmp_path / "less"
    shutil.copytree(root / "a", less)
    next(less.glob(f"evaluate/*/{DONE_FILE}")).unlink()
    with pytest.raises(ExportError, match="holds 1 evaluation"):
        export_experiment(spec, carried, "quick", 2, less)
    export_experiment(spec, carried, "quick", 2, root / "a")  # the same again: replaced
    (carried / INDEX_FILE).write_text("{")  # e.g. a merge conflict: it may hold anything
    with pytest.raises(ExportError, match="index cannot be read"):
        export_experiment(spec, carried, "quick", 2, less)
    assert len(list(carried.glob("evaluate/*"))) == 2
    assert main(["reproduce", spec, "--work", str(root / "a"), "--runs", "2",
                 "--export-stages", str(tmp_path / "cli")]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "2 evaluation(s) and 4 record(s)" in out and "--runs 2 --import-stages" in out
    assert main(["reproduce", spec, "--export-stages", str(carried), "--estimate"]) == 1
    assert "--export-stages runs nothing else: drop --estimate" in capsys.readouterr().err
    assert main(["reproduce", spec, "--work", str(tmp_path / "w"), "--estimate",
                 "--import-stages", str(tmp_path)]) == 1  # fmt: skip
    assert "is no readable export of finished stages" in capsys.readouterr().err


def _noop(out: Path) -> None:
    """A stage that writes nothing (its runner marks it done)."""


def _mark(stage: Stage, work: Path) -> None:
    """``stage`` finished elsewhere: its record, as an import copies it in."""
    stage.path(work).mkdir(parents=True)
    record = {"kind": stage.kind, "config": stage.config, "wall_s": 0.0}
    (stage.path(work) / DONE_FILE).write_text(json.dumps(record))


def test_needed_stages_leave_out_what_only_done_stages_read(tmp_path):
    col = Stage("collect", "collect", {"i": 0}, _noop)
    fil = Stage("filter", "filter", {"i": 1}, _noop, (col,))
    tr = Stage("train", "train", {"i": 2}, _noop, (col, fil))
    ev = Stage("evaluate", "eval", {"i": 3}, _noop, (tr,))
    plan = [col, fil, tr, ev]
    assert needed_stages(plan, tmp_path, [fil, ev]) == plan  # nothing done: everything
    _mark(ev, tmp_path)  # the evaluation came with an import
    assert needed_stages(plan, tmp_path, [fil, ev]) == [col, fil, ev]  # no training
    assert needed_stages(plan, tmp_path, [ev]) == [ev]  # nor a collection nobody reads
    # with two jobs the done evaluation is reported cached although its training is not planned
    runner = StageRunner(tmp_path, total=3, echo=lambda s: None)
    command = lambda s: [sys.executable, "-c", "raise SystemExit(3)"]  # noqa: E731
    run_stages([col, fil, ev], runner, jobs=2, worker_command=command)
    assert [e["cached"] for e in runner.log] == [False, False, True]
    assert col.done(tmp_path) and fil.done(tmp_path) and not tr.done(tmp_path)
