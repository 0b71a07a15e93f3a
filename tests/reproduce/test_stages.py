"""The stage cache's "done" mark: only a finished stage's own record counts."""

import json

import pytest

from lhf_hf.reproduce.stages import DONE_FILE, Stage, StageRunner, done_record, stage_wall


def _stage(calls: list) -> Stage:
    def fn(out):
        calls.append(out)
        (out / "output.txt").write_text(f"run {len(calls)}")

    return Stage(kind="filter", label="a filter", config={"lam": 1.0}, fn=fn)


def test_a_finished_stage_is_cached(tmp_path):
    calls, lines = [], []
    stage = _stage(calls)
    runner = StageRunner(tmp_path, echo=lines.append)
    out = runner.run(stage)
    assert stage.done(tmp_path) and len(calls) == 1
    record = done_record(out)
    assert record["kind"] == "filter" and record["config"] == {"lam": 1.0}
    StageRunner(tmp_path, echo=lines.append).run(stage)
    assert len(calls) == 1 and lines[-1].endswith(f": cached ({out})")


@pytest.mark.parametrize(
    "text",
    [
        "[]",
        '"done"',
        "null",
        "{}",
        '{"kind": "filter"}',  # no wall time
        '{"kind": "filter", "wall_s": "3"}',
        '{"kind": "filter", "wall_s": NaN}',
        '{"kind": "filter", "wall_s": -1}',
        '{"kind": "filter", "wall_s": true}',
        '{"kind": 5, "wall_s": 3}',
        '{"kind": "train", "wall_s": 3}',  # another kind's record
        '{"kind": "filter", "wall_s": 0}',  # no config
        '{"kind": "filter", "wall_s": 0, "config": {"lam": 2.0}}',  # another stage's config
        '{"kind": "filter", "wall_s": 0, "config": [1]}',
        '{"kind": "filter", "wall_s": 3',  # cut short
        "",
    ],
)
def test_a_stage_json_that_is_no_record_runs_the_stage_again(tmp_path, text):
    calls, lines = [], []
    stage = _stage(calls)
    out = StageRunner(tmp_path, echo=lines.append).run(stage)
    (out / DONE_FILE).write_text(text)
    assert not stage.done(tmp_path)
    StageRunner(tmp_path, echo=lines.append).run(stage)
    assert len(calls) == 2 and (out / "output.txt").read_text() == "run 2"
    again = json.loads((out / DONE_FILE).read_text())
    # The rerun found the earlier output: it resumed, so its wall time is no rate.
    assert again["kind"] == "filter" and again["resumed"] is True
    assert stage.done(tmp_path)


def test_done_record_of_a_missing_folder_is_none(tmp_path):
    assert done_record(tmp_path / "absent") is None


def test_a_record_copied_from_another_stage_is_not_this_ones(tmp_path):
    calls: list = []
    a, b = _stage(calls), _stage(calls)
    b.config = {"lam": 2.0}
    runner = StageRunner(tmp_path, echo=lambda s: None)
    runner.run(a)
    b.path(tmp_path).mkdir(parents=True)
    (b.path(tmp_path) / DONE_FILE).write_bytes((a.path(tmp_path) / DONE_FILE).read_bytes())
    assert a.done(tmp_path) and not b.done(tmp_path)


def test_stage_wall_is_a_number_whatever_the_mark(tmp_path):
    calls: list = []
    stage = _stage(calls)
    out = StageRunner(tmp_path, echo=lambda s: None).run(stage)
    assert stage_wall(out) == json.loads((out / DONE_FILE).read_text())["wall_s"]
    found = json.loads((out / DONE_FILE).read_text())
    (out / DONE_FILE).write_text(json.dumps({**found, "wall_s": float("nan")}))
    assert (
        stage_wall(out) == 0.0
    )  # was NaN: a table's stage time became "nan h", results.json not JSON
    (out / DONE_FILE).unlink()
    (out / "stage.record.json").write_text(json.dumps({"wall_s": 12.5}))  # an imported record
    assert stage_wall(out) == 12.5
    (out / "stage.record.json").write_text('{"wall_s": "12"}')
    assert stage_wall(out) == 0.0
