"""lhf verify and the checks on load: a changed, inconsistent or foreign artifact is named, not used."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from lhf_hf import constants as C
from lhf_hf.cli.main import main
from lhf_hf.histories.reader import DatasetFormatError, load_histories
from lhf_hf.verify import verify


@pytest.fixture()
def data(small_darkroom_batched, tmp_path):
    root = tmp_path / "data"
    shutil.copytree(small_darkroom_batched.root, root)
    return root


def _rewrite(path, fn):
    table = pq.read_table(path)
    pq.write_table(fn(table), path)


def test_a_sound_dataset_verifies(data, capsys):
    r = verify(data)
    assert (r["kind"], r["manifest"], r["problems"]) == ("dataset", True, [])
    assert main(["verify", str(data)]) == 0
    assert "(dataset): ok" in capsys.readouterr().out


def test_changed_frames_are_found(data, capsys):
    """One reward changed in a data file: the manifest, the fingerprint and the returns say so."""
    f = data / C.DATA_PATH.format(chunk_index=0, file_index=1)

    def bump(t):
        r = t.column(C.REWARD).to_numpy().copy()
        r[5] += 1.0
        return t.set_column(t.schema.get_field_index(C.REWARD), C.REWARD, pa.array(r))

    _rewrite(f, bump)
    problems = verify(data)["problems"]
    assert any("file-001.parquet: changed" in p for p in problems)
    assert any("fingerprint" in p for p in problems)
    assert any("not its frames' reward sums" in p for p in problems)
    assert main(["verify", str(data)]) == 1
    assert "problem(s)" in capsys.readouterr().out


@pytest.mark.parametrize(
    "damage, message",
    [
        (
            lambda t: t.set_column(
                t.schema.get_field_index(C.RETURNS),
                C.RETURNS,
                pa.array(
                    [[float("nan")] * len(r) for r in t.column(C.RETURNS).to_pylist()],
                    type=pa.list_(pa.float32()),
                ),
            ),  # fmt: skip
            "returns contain NaN or infinite values",
        ),
        (
            lambda t: t.set_column(
                t.schema.get_field_index(C.TASK_ID),
                C.TASK_ID,
                pa.array(np.full(t.num_rows, 7, np.int64)),
            ),  # fmt: skip
            "task_id values do not match",
        ),
    ],
)
def test_an_inconsistent_histories_table_is_refused_on_load(data, damage, message):
    _rewrite(data / C.HISTORIES_PATH, damage)
    with pytest.raises(DatasetFormatError, match=message):
        load_histories(data)


def test_any_edit_of_the_meta_tables_is_caught_on_load(data, tmp_path, capsys):
    """The histories table is checked against the manifest on every load: a fabricated return of
    any task (not only the one whose rewards are summed) is refused before LHF scores it."""

    def fabricate(t):
        rows = t.column(C.RETURNS).to_pylist()
        rows[-1] = [20.0] * len(rows[-1])  # the last task's last history
        return t.set_column(t.schema.get_field_index(C.RETURNS), C.RETURNS,
                            pa.array(rows, type=pa.list_(pa.float32())))  # fmt: skip

    _rewrite(data / C.HISTORIES_PATH, fabricate)
    with pytest.raises(DatasetFormatError, match="histories/chunk-000/file-000.parquet: changed"):
        load_histories(data)
    assert main(["filter", str(data), "--out", str(tmp_path / "s")]) == 1


def test_info_totals_missing_columns_and_corrupt_files_are_named(data):
    info = json.loads((data / C.INFO_PATH).read_text())
    info["total_frames"] += 1
    (data / C.INFO_PATH).write_text(json.dumps(info))
    with pytest.raises(DatasetFormatError, match="info.json says"):
        load_histories(data)
    info["total_frames"] -= 1
    (data / C.INFO_PATH).write_text(json.dumps(info))
    f = data / C.DATA_PATH.format(chunk_index=0, file_index=2)
    _rewrite(f, lambda t: t.drop_columns([C.NEXT_OBS]))
    with pytest.raises(
        DatasetFormatError,
        match=r"file-002.parquet: lacks the frame columns \['next.observation.state'\]",
    ):
        load_histories(data)
    (data / C.HISTORIES_PATH).write_bytes(b"PAR1 truncated")
    with pytest.raises(
        DatasetFormatError, match=r"histories/chunk-000/file-000.parquet is not a readable parquet"
    ):
        load_histories(data)


def test_a_selection_of_another_histories_table_is_refused(data, tmp_path, capsys):
    sel = tmp_path / "sel"
    assert main(["filter", str(data), "--out", str(sel)]) == 0
    assert verify(sel)["problems"] == []
    # same frames, histories rows reordered: the frames' fingerprint is unchanged, the table not
    # (no manifest, as in a dataset written before manifests: the load's own check cannot see it)
    (data / ".lhf_output.json").unlink()
    _rewrite(data / C.HISTORIES_PATH, lambda t: t.take(pa.array(np.arange(t.num_rows)[::-1])))
    capsys.readouterr()
    args = ["train", "--dataset", str(data), "--selection", str(sel), "--objective", "ad",
            "--preset", "tiny", "--max-steps", "2", "--batch-size", "2", "--out", str(tmp_path / "m")]  # fmt: skip
    assert main(args) == 1
    assert "histories table of" in capsys.readouterr().err
    assert any("histories table" in p for p in verify(sel)["problems"])


def test_models_verify_and_pickles_are_refused(data, tmp_path, capsys):
    model = tmp_path / "m"
    args = ["train", "--dataset", str(data), "--objective", "ad", "--preset", "tiny",
            "--max-steps", "2", "--batch-size", "2", "--out", str(model)]  # fmt: skip
    assert main(args) == 0
    ev = [
        "evaluate",
        "--model",
        str(model),
        "--episodes",
        "1",
        "--tasks",
        "38",
        "--out",
        str(model / "eval"),
    ]
    assert main(ev) == 0  # updates the card: mutable, and eval/ is its own artifact
    assert verify(model)["problems"] == [] and verify(model / "eval")["problems"] == []
    (model / "model.safetensors").write_bytes(
        (model / "model.safetensors").read_bytes()[:-8] + b"\0" * 8
    )
    assert any("model.safetensors: changed" in p for p in verify(model)["problems"])
    pickled = tmp_path / "pickled"
    pickled.mkdir()
    shutil.copy(model / "config.json", pickled / "config.json")
    (pickled / "pytorch_model.bin").write_bytes(b"not loaded")
    capsys.readouterr()
    assert main(["evaluate", "--model", str(pickled), "--out", str(tmp_path / "e")]) == 1
    err = capsys.readouterr().err
    assert "pickled weights (pytorch_model.bin) only" in err and "Traceback" not in err


def test_verify_errors(tmp_path, capsys):
    assert main(["verify", str(tmp_path / "none")]) == 1
    assert "no folder at" in capsys.readouterr().err
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "a.txt").write_text("a")
    assert main(["verify", str(tmp_path / "x")]) == 1
    assert "not an lhf output folder" in capsys.readouterr().err


def test_an_evaluation_without_manifest_is_recognised_and_checked(tmp_path):
    from lhf_hf.verify import verify

    ev = tmp_path / "ev"
    ev.mkdir()
    result = {
        "config": {"rollouts": 1},
        "objective": "ad",
        "env_id": "darkroom",
        "mean_curve": [0.0, 1.5],
    }
    (ev / "eval_results.json").write_text(json.dumps(result))
    r = verify(ev)
    assert (r["kind"], r["manifest"], r["problems"]) == ("evaluation", False, [])
    assert "no .lhf_output.json" in r["notes"][0]
    (ev / "eval_results.json").write_text(json.dumps({**result, "mean_curve": [float("nan")]}))
    assert "not a finite number" in verify(ev)["problems"][0]


def test_each_problem_is_printed_once(data, tmp_path, capsys):
    """A changed meta file is the manifest's finding; the dataset's deep check (which every load
    runs with the meta files against the manifest) does not report it again, nor does an
    evaluation's results check repeat the manifest's "changed"."""
    (data / C.STATS_PATH).write_text("{}")
    r = verify(data)
    assert r["problems"] == ["meta/stats.json: changed (SHA-256 differs from the recorded one)"]
    assert main(["verify", str(data)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out == [
        f"{data} (dataset): 1 problem(s)",
        "  - meta/stats.json: changed (SHA-256 differs from the recorded one)",
    ]
    with pytest.raises(DatasetFormatError, match="meta/stats.json: changed"):
        load_histories(data)  # a reader still checks the meta files

    from lhf_hf.utils.outputs import output_folder

    result = {"config": {}, "objective": "ad", "env_id": "darkroom", "mean_curve": [1.0]}
    with output_folder(tmp_path / "ev", "evaluation") as ev:
        (ev / "eval_results.json").write_text(json.dumps(result))
    (ev / "eval_results.json").write_text(json.dumps({**result, "mean_curve": [2.0]}))
    changed = "eval_results.json: changed (SHA-256 differs from the recorded one)"
    assert verify(ev)["problems"] == [changed]
    (ev / "eval_results.json").unlink()
    assert verify(ev)["problems"] == ["eval_results.json: missing"]


def test_a_models_dataset_is_checked_with_its_meta_files(data, tmp_path):
    """Verifying a model still checks its dataset's meta files against their manifest (the
    dataset's deep check leaves them to the caller)."""
    from lhf_hf.configs import TrainConfig
    from lhf_hf.training import train

    model = tmp_path / "m"
    train(TrainConfig(dataset=str(data), objective="ad", out=str(model), preset="tiny",
                      batch_size=4, context_length=20, max_steps=1, save_steps=1))  # fmt: skip
    assert verify(model)["problems"] == []
    (data / C.STATS_PATH).write_text("{}")
    assert verify(model)["problems"] == [
        f"its dataset {data}: meta/stats.json: changed (SHA-256 differs from the recorded one)"
    ]
