"""results/README.md: every table's cells, our E beside the paper's, from their results.json."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.scripts import load_script

render_index, write_index = (
    load_script("results_index").render_index,
    load_script("results_index").write_index,
)


def _row(backbone, e, e_std, ci=None, base=4.0, lhf=5.0, **paired):
    return dict(
        backbone=backbone, E=e, E_std=e_std, E_ci95=ci, baseline_mean=base, lhf_mean=lhf, **paired
    )


def _table(root: Path, name: str, cells: list, paper: dict, stage_s=None, selections=None) -> None:
    summary = {
        "experiment": {"name": name, "title": f"Title of {name}", "preset": "cpu", "runs": 3,
                       "paper": paper},
        "cells": cells,
        "created": "2027-01-02T00:00:00+0000",
    }  # fmt: skip
    if stage_s is not None:
        summary["stage_s"] = stage_s
    if selections is not None:
        summary["selections"] = selections
    (root / f"{name}-cpu").mkdir(parents=True)
    (root / f"{name}-cpu" / "results.json").write_text(json.dumps(summary))
    (root / f"{name}-cpu" / "report.md").write_text("# report")


def test_index_lists_every_cell_with_paper_value_interval_verdict_and_hours(tmp_path):
    root = tmp_path / "results"  # the command lines are run from its parent
    root.mkdir()
    _table(root, "b-noisy", [{"env_id": "darkroom", "arm": "lhf", "rows": [
        # paired run means recorded by an older table (a population std, the interval of the
        # mean per-run E, no E_mde80, no differences): all restated from the run means
        _row("AD", 1.2, 0.3, [0.5, 1.9], 4.0, 6.0, baseline_run_means=[4, 4, 4],
             lhf_run_means=[5, 6, 7]),
        _row("DICP + plan", -0.1, 0.5),
        # no run means: shown as recorded, marked, and judged on the recorded interval
        _row("DICP + plan, gated", 1.2, 0.3, [0.5, 1.9], 4.33, 9.51),
        # E's interval spans 0 but the paired return differences' excludes it: the latter decides
        _row("DPT", 2.37, 2.66, [-4.6, 11.6], 1.49, 5.04, diff=3.54, diff_ci95=[1.47, 5.61]),
        # a baseline returning 0: E undefined (null in JSON), the difference still decides
        _row("DICP", None, None, None, 0.0, 5.04, diff=5.04, diff_ci95=[4.07, 6.0]),
    ]}], {"darkroom": {"ad": 90.7, "dicp": 19.0}}, stage_s=7200, selections=[
        {"env_id": "darkroom", "arm": "lhf", "run": r, "mean_return_selected_unique": k,
         "mean_return_rejected": j} for r, (k, j) in enumerate([(10.0, 12.0), (11.0, 13.0)])
    ])  # fmt: skip
    _table(root, "a-main", [{"env_id": "darkroom-large", "arm": "lam2", "rows": [
        _row("DPT", 0.05, None),
    ]}], {})  # fmt: skip
    (root / "not-a-table").mkdir()
    (root / "a-main-cpu" / "report.md").unlink()  # no report: the title is not a link
    text, bad = render_index(root)
    assert bad == []
    # tables in name order, each linking its report
    assert text.index("## Title of a-main") < text.index("## [Title of b-noisy](b-noisy-cpu/")
    assert "(a-main-cpu/report.md)" not in text
    assert "`lhf reproduce b-noisy --preset cpu --runs 3`; 2.00 h of stage time" in text
    # by hand: per-run E 0.25, 0.5, 0.75 (sample std 0.25); differences 1, 2, 3 (mean 2, std 1):
    # CI 2 +/- t(0.975, 2) / sqrt(3) = 2 +/- 2.484; E's delta interval 0.5 +/- 4.3027 sqrt(1/48)
    assert (
        "| darkroom | AD | +50.0 ± 25.0 | -12.1 .. +112.1 | +90.7 | +77.4 | no clear effect (the "
        "paired return difference's 95% CI spans 0) | 4.00 -> 6.00 (difference +2.00, 95% CI "
        "-0.48 .. +4.48) |" in text
    )
    recorded = " (as recorded: population std, interval of the mean per-run E)"
    assert (
        f"| darkroom | DICP + plan, gated | +120.0 ± 30.0{recorded} | +50.0 .. +190.0 | - | - "
        "| helps (E's 95% CI; no paired test recorded) | 4.33 -> 9.51 |" in text
    )
    assert (
        f"| darkroom | DPT | +237.0 ± 266.0{recorded} | -460.0 .. +1160.0 | - | - | helps "
        "| 1.49 -> 5.04 (difference +3.54, 95% CI +1.47 .. +5.61) |" in text
    )
    # the paper's DICP value (the reference planner's) beside `DICP + plan` only
    assert "| darkroom | DICP | - | - | - | - | helps | 0.00 -> 5.04 (difference +5.04" in text
    # the paper's DICP value stands beside DICP + plan; a verdict's pipe is escaped in the cell
    assert (
        f"| darkroom | DICP + plan | -10.0 ± 50.0{recorded} | - | +19.0 | - | no clear effect (\\|E\\|"
        in text
    )
    # an arm other than lhf is named; no paper value, one run (no std)
    assert (
        "| darkroom-large (lam2) | DPT | +5.0 | - | - | - | not judged (1 paired run, no error bar): the return is higher with LHF |"
        in text
    )
    assert "not-a-table" not in text
    # what LHF kept, averaged over the runs; a table made before it was recorded says nothing
    assert (
        "LHF kept on darkroom: histories with mean return 10.50 vs 12.50 for those it rejected (mean over 2 run(s))."
        in text
    )
    assert text.count("LHF kept") == 1


def test_index_names_an_unreadable_table_and_refuses_a_missing_root(tmp_path):
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "results.json").write_text("{not json")
    (tmp_path / "keys").mkdir()
    (tmp_path / "keys" / "results.json").write_text("[]")
    text, bad = render_index(tmp_path)
    assert bad == ["broken", "keys"]
    assert "## broken" in text and "`results.json` unreadable: " in text
    with pytest.raises(FileNotFoundError, match="no results folder"):
        render_index(tmp_path / "missing")


def test_index_names_a_narrowed_table_s_command(tmp_path):
    root = tmp_path / "results"  # the command lines are run from its parent
    root.mkdir()
    _table(root, "n", [], {})
    path = root / "n-cpu" / "results.json"
    summary = json.loads(path.read_text())
    summary["experiment"].update(narrowed=True, objectives=["dicp"])
    path.write_text(json.dumps(summary))
    # not the narrowed command's default folder (results/n-cpu-dicp): --out names it
    assert (
        f"`lhf reproduce n --preset cpu --runs 3 --objectives dicp --out {root.name}/n-cpu`"
        in render_index(root)[0]
    )
    (root / "n-cpu").rename(root / "n-cpu-dicp")
    assert "`lhf reproduce n --preset cpu --runs 3 --objectives dicp`;" in render_index(root)[0]


def test_index_names_a_custom_spec_by_its_recorded_path(tmp_path):
    root = tmp_path / "results"  # the command lines are run from its parent
    root.mkdir()
    _table(root, "c", [], {})
    path = root / "c-cpu" / "results.json"
    assert "`lhf reproduce c --preset cpu --runs 3`;" in render_index(root)[0]  # no spec: name
    summary = json.loads(path.read_text())
    summary["experiment"]["spec"] = "specs/c.yaml"
    path.write_text(json.dumps(summary))
    assert "`lhf reproduce specs/c.yaml --preset cpu --runs 3`;" in render_index(root)[0]
    # a custom spec named like a shipped one: its folder is written even when it is the default
    _table(root, "darkroom-main", [], {})
    path = root / "darkroom-main-cpu" / "results.json"
    summary = json.loads(path.read_text())
    summary["experiment"]["spec"] = "mine/darkroom-main.yaml"
    path.write_text(json.dumps(summary))
    expected = "`lhf reproduce mine/darkroom-main.yaml --preset cpu --runs 3 --out results/darkroom-main-cpu`;"
    assert expected in render_index(root)[0]


def test_index_cells_without_a_finite_e_no_cells_and_odd_names(tmp_path):
    _table(tmp_path, "one run", [{"env_id": "darkroom", "arm": "lhf", "rows": [
        _row("AD", None, None, base=0.0, lhf=1.0),
        _row("DPT", float("inf"), float("nan")),
    ]}], {})  # fmt: skip
    _table(tmp_path, "empty", [], {})
    text, bad = render_index(tmp_path)
    assert bad == []
    assert "| darkroom | AD | - | - | - | - | undefined (no finite E) | 0.00 -> 1.00 |" in text
    assert "| darkroom | DPT | - | - | - | - | undefined (no finite E) | 4.00 -> 5.00 |" in text
    assert "](one%20run-cpu/report.md)" in text  # a link that works with a space in the name
    assert "No cells: the table compared nothing." in text


@pytest.mark.slow
def test_empty_root_and_the_script_writes_readme(tmp_path):
    assert "No tables yet" in render_index(tmp_path)[0]
    _table(tmp_path, "x", [{"env_id": "darkroom", "arm": "lhf", "rows": [_row("AD", 0.1, 0.2)]}],
           {"darkroom": {"ad": 25.1}})  # fmt: skip
    assert write_index(tmp_path) == (tmp_path / "README.md", [])
    script = Path(__file__).parents[2] / "scripts" / "results_index.py"
    out = subprocess.run([sys.executable, str(script), "--root", str(tmp_path)],
                         capture_output=True, text=True, check=True)  # fmt: skip
    assert out.stdout.strip() == str(tmp_path / "README.md")
    assert (
        "| darkroom | AD | +10.0 ± 20.0 (as recorded: population std, interval of the mean per-run E) | - | +25.1 |"
        in (tmp_path / "README.md").read_text()
    )
    bad = subprocess.run([sys.executable, str(script), "--root", str(tmp_path / "none")],
                         capture_output=True, text=True)  # fmt: skip
    assert bad.returncode == 1 and "no results folder" in bad.stderr
    bad = subprocess.run([sys.executable, str(script), "--root", str(tmp_path / "x-cpu")],
                         capture_output=True, text=True)  # fmt: skip
    assert bad.returncode == 1 and "is one table's folder" in bad.stderr
    assert not (tmp_path / "x-cpu" / "README.md").exists()
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "results.json").write_text("{")
    bad = subprocess.run([sys.executable, str(script), "--root", str(tmp_path)],
                         capture_output=True, text=True)  # fmt: skip
    assert bad.returncode == 2 and "unreadable results.json in: broken" in bad.stderr
    assert "## broken" in (tmp_path / "README.md").read_text()  # written all the same


def test_index_states_each_tables_recorded_budget(tmp_path):
    """Two tables from the same command line, made before and after a preset changed, differ in the
    histories per goal and the steps their results.json recorded; the index shows both."""
    root = tmp_path / "results"  # the command lines are run from its parent
    root.mkdir()
    rows = [{"env_id": "darkroom", "arm": "lhf", "rows": [_row("AD", 0.1, 0.1)]}]
    _table(root, "old", rows, {})
    _table(root, "new", rows, {})
    _table(root, "none", rows, {})  # nothing recorded: no budget facts, no error
    for name, collect, train, objectives in [
        ("old", {"histories": 50}, {"max_steps": 1000}, ["ad", "dicp"]),
        ("new", {"histories": 100}, {"max_steps": 3000, "by_objective": {"dicp": {"max_steps": 4000}}},
         ["ad", "dicp"]),
    ]:  # fmt: skip
        path = root / f"{name}-cpu" / "results.json"
        summary = json.loads(path.read_text())
        summary["experiment"].update(collect=collect, train=train, objectives=objectives)
        path.write_text(json.dumps(summary))
    text, bad = render_index(root)
    assert bad == []
    assert (
        "`lhf reproduce old --preset cpu --runs 3`; 50 histories per goal; 1,000 training steps;"
        in text
    )
    assert (
        "`lhf reproduce new --preset cpu --runs 3`; 100 histories per goal; ad 3,000 / dicp 4,000 "
        "training steps;" in text
    )
    assert "`lhf reproduce none --preset cpu --runs 3`; 2027-01-02T00:00:00+0000." in text


def test_command_lines_under_any_root_run_from_its_parent(tmp_path, monkeypatch):
    """Under a root not named ``results`` every table's folder is named (the default one would be
    ``results/NAME``), relative to the root's parent, which the page names; a root given as ``.``
    still has its own name.  An empty root (the current folder) and a file are refused."""
    root = tmp_path / "mine"
    root.mkdir()
    _table(root, "c", [], {})
    text = render_index(root)[0]
    assert "`lhf reproduce c --preset cpu --runs 3 --out mine/c-cpu`;" in text
    assert "The command lines run from the folder that holds `mine/`." in text
    monkeypatch.chdir(root)
    assert "`lhf reproduce c --preset cpu --runs 3 --out mine/c-cpu`;" in render_index(".")[0]
    with pytest.raises(ValueError, match="is empty"):
        render_index("")
    (tmp_path / "f").write_text("x")
    with pytest.raises(NotADirectoryError, match="is a file"):
        render_index(tmp_path / "f")
    results = tmp_path / "results"
    results.mkdir()
    assert "The command lines run from" not in render_index(results)[0]


def test_a_symlinked_results_folder_keeps_its_name(tmp_path):
    """``results -> /store/x``: the command lines name ``results/``, not where it points."""
    store = tmp_path / "store" / "elsewhere"
    store.mkdir(parents=True)
    _table(store, "c", [], {})
    (tmp_path / "proj").mkdir()
    (tmp_path / "proj" / "results").symlink_to(store, target_is_directory=True)
    text = render_index(tmp_path / "proj" / "results")[0]
    assert "`lhf reproduce c --preset cpu --runs 3`;" in text
    assert "The command lines run from" not in text


def test_older_tables_are_judged_on_what_they_recorded():
    """Tables made before the paired differences were recorded are judged on E's 95% interval,
    older ones on |E| against its std; a recorded difference interval decides as in the report."""
    judged = load_script("results_index").judged
    # each verdict not made by the paired test says what made it
    assert judged(0.10, 0.05, None, None) == "helps (|E| beyond its std; no paired test recorded)"
    assert judged(-0.10, 0.05, None, None) == "hurts (|E| beyond its std; no paired test recorded)"
    assert judged(0.03, 0.05, None, None) == "no clear effect (|E| within its std)"
    assert judged(0.03, None, None, None).endswith("higher with LHF")  # one run: its sign
    assert judged(None, None, None, None) == "undefined (no finite E)"
    # an interval decides over the std: an effect beyond 1 std whose interval spans 0 is none
    assert judged(-0.194, 0.098, (-0.482, 0.113), None) == "no clear effect (the 95% CI spans 0)"
    assert judged(0.10, 0.50, (0.01, 0.19), None) == "helps (E's 95% CI; no paired test recorded)"
    assert judged(-0.1, 0.5, (-0.2, -0.01), None) == "hurts (E's 95% CI; no paired test recorded)"
    # the paired differences' interval decides over both, E undefined or not
    assert judged(2.37, 2.66, (-4.6, 11.6), (1.47, 5.61)) == "helps"
    assert judged(None, None, None, (4.07, 6.0)) == "helps"
