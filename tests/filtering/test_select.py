"""Selections on a real collected dataset: provenance, frames with multiplicity, materialisation, CLI."""

import json
import shutil

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from lhf_hf import constants as C
from lhf_hf.cli.main import main
from lhf_hf.configs import FilterConfig
from lhf_hf.filtering import (
    apply_selection,
    filter_frames,
    filter_histories,
    load_selection,
    materialize,
)
from lhf_hf.histories import load_histories
from tests.trees import tree_digest


@pytest.fixture(scope="module")
def selection(small_darkroom):
    return filter_histories(small_darkroom, FilterConfig())


def test_selection_keeps_task_sizes_and_prefers_ppo(selection, small_darkroom):
    t = selection.table.to_pandas()
    assert t.groupby(C.TASK_ID)["count"].sum().tolist() == [10, 10, 10]
    s = selection.summary()
    assert s["share_in_source"]["random"] == pytest.approx(0.3)
    assert s["share_in_selection"]["random"] < 0.3
    assert selection.source["fingerprint"] == small_darkroom.fingerprint


def test_save_and_load(selection, tmp_path):
    selection.save(tmp_path / "sel")
    meta = json.loads((tmp_path / "sel" / "filter_config.json").read_text())
    assert meta["filter"]["strategy"] == "linear" and meta["filter"]["lam"] == 1.0
    assert len(meta["source"]["histories_fingerprint"]) == 64 and "datasets" in meta["versions"]
    again = load_selection(tmp_path / "sel")
    assert again.table.equals(selection.table) and again.config == selection.config
    sel = pq.read_table(tmp_path / "sel" / "selection.parquet")
    assert pa.compute.min(sel.column("count")).as_py() >= 1
    with pytest.raises(FileNotFoundError, match="not a selection folder"):
        load_selection(tmp_path)


def test_apply_selection_repeats_contiguous_histories(selection, small_darkroom):
    frames = apply_selection(small_darkroom, selection)
    counts = selection.counts()
    assert frames.num_rows == sum(counts.values()) * 200
    h = np.asarray(frames.data.column(C.HISTORY_INDEX).to_numpy())
    blocks = h.reshape(-1, 200)
    assert np.all(blocks == blocks[:, :1])  # every block of 200 frames is one whole history
    ids, reps = np.unique(blocks[:, 0], return_counts=True)
    assert dict(zip(ids.tolist(), reps.tolist(), strict=True)) == {
        k: v for k, v in counts.items() if v
    }


def test_filter_frames_drops_histories(small_darkroom):
    kept = filter_frames(small_darkroom.frames, [0, 5, 29])
    assert kept.num_rows == 600 and set(kept[C.HISTORY_INDEX]) == {0, 5, 29}


def test_materialize(selection, small_darkroom, tmp_path):
    new = materialize(small_darkroom, selection, tmp_path / "m", progress=False)
    assert new.lhf["total_histories"] == 30 and new.info["total_frames"] == 6000
    d = new.lhf["derived_from"]
    assert (
        d["op"] == "lhf"
        and d["filter"]["strategy"] == "linear"
        and d["source_fingerprint"] == small_darkroom.fingerprint
    )
    counts = selection.counts()
    src = small_darkroom.histories.to_pandas().set_index(C.HISTORY_INDEX)
    new_returns = [tuple(r) for r in new.histories.to_pandas()[C.RETURNS]]
    for h, c in counts.items():
        assert new_returns.count(tuple(src.loc[h, C.RETURNS])) >= c
    assert "lhf" in (new.root / "README.md").read_text()
    # indices are renumbered: histories are contiguous again
    idx = new.frame_table([C.INDEX]).column(C.INDEX).to_numpy()
    np.testing.assert_array_equal(idx, np.arange(6000))


def test_selection_from_another_dataset_is_refused(selection, small_darkroom, tmp_path):
    other = type(selection)(
        selection.table, selection.config, {**selection.source, "fingerprint": "0" * 64}
    )
    with pytest.raises(ValueError, match="selection was made from the dataset with fingerprint"):
        apply_selection(small_darkroom, other)


def test_cli_end_to_end(small_darkroom, tmp_path, capsys):
    out = tmp_path / "sel"
    assert (
        main(
            [
                "filter",
                str(small_darkroom.root),
                "--out",
                str(out),
                "--strategy",
                "softmax",
                "--alpha",
                "0.25",
                "--materialize",
                str(tmp_path / "mat"),
            ]
        )
        == 0
    )
    summary = json.loads(capsys.readouterr().out.split("\nselection:")[0])
    assert (
        summary["histories"] == 30
        and summary["mean_return_selection"] >= summary["mean_return_source"]
    )
    assert (out / "selection.png").read_bytes()[:4] == b"\x89PNG"
    assert (tmp_path / "mat" / "meta" / "selection.png").exists()
    # both folders verify: the plot is in the materialised dataset's manifest, not added after it
    assert main(["verify", str(tmp_path / "mat")]) == 0
    assert main(["verify", str(out)]) == 0
    capsys.readouterr()
    assert load_histories(tmp_path / "mat").lhf["derived_from"]["filter"]["alpha"] == 0.25
    assert main(["filter", str(small_darkroom.root), "--out", str(out)]) == 1
    assert "--overwrite" in capsys.readouterr().err


def test_cli_bad_input_writes_nothing(small_darkroom, tmp_path, capsys):
    assert (
        main(["filter", str(small_darkroom.root), "--out", str(tmp_path / "a"), "--alpha", "-1"])
        == 1
    )
    assert "alpha" in capsys.readouterr().err and not (tmp_path / "a").exists()
    bad = tmp_path / "nan"
    shutil.copytree(small_darkroom.root, bad)
    hist = pq.read_table(bad / C.HISTORIES_PATH).to_pydict()
    hist[C.RETURNS][4] = [float("nan")] + hist[C.RETURNS][4][1:]
    pq.write_table(
        pa.Table.from_pydict(hist, schema=pq.read_schema(bad / C.HISTORIES_PATH)),
        bad / C.HISTORIES_PATH,
    )
    assert main(["filter", str(bad), "--out", str(tmp_path / "b")]) == 1
    assert "history 4: returns contain NaN" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


@pytest.mark.slow
@pytest.mark.parametrize("when", ["after the selection's last write", "in materialize's writes"])
def test_an_interrupted_overwrite_keeps_selection_and_materialised_data_paired(
    small_darkroom, tmp_path, monkeypatch, capsys, when
):
    """Ctrl-C once the new materialised dataset has switched but before the selection has (or
    earlier): both old copies come back, so the dataset still matches its selection."""
    from lhf_hf.filtering import run as run_mod
    from lhf_hf.filtering.run import run_filter

    sel, mat = tmp_path / "sel", tmp_path / "mat"
    run_filter(small_darkroom.root, sel, FilterConfig(), materialize=mat, progress=False)
    before = tree_digest(sel), tree_digest(mat)
    if when == "in materialize's writes":

        def boom(*args, **kwargs):
            raise KeyboardInterrupt

        monkeypatch.setattr(run_mod, "materialize_histories", boom)
    else:
        from lhf_hf.filtering.select import Selection

        saves = []
        real_save = Selection.save

        def save_then_stop(self, *args, **kwargs):
            saves.append(1)
            if len(saves) == 2:  # the summary re-saved after materialize
                raise KeyboardInterrupt
            return real_save(self, *args, **kwargs)

        monkeypatch.setattr(Selection, "save", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        run_filter(small_darkroom.root, sel, FilterConfig(lam=0.0), materialize=mat,
                   overwrite=True, progress=False)  # fmt: skip
    assert (tree_digest(sel), tree_digest(mat)) == before
    assert not list(tmp_path.glob(".*.replaced-*"))
    monkeypatch.undo()
    run_filter(small_darkroom.root, sel, FilterConfig(lam=0.0), materialize=mat, overwrite=True,
               progress=False)  # fmt: skip
    assert load_histories(mat).lhf["derived_from"]["filter"]["lam"] == 0.0
    assert json.loads((sel / "filter_config.json").read_text())["filter"]["lam"] == 0.0


@pytest.mark.slow
def test_selection_card_commands_run_and_a_pushed_card_names_no_local_path(
    small_darkroom, tmp_path, monkeypatch
):
    import re
    import shlex

    from lhf_hf.filtering.card import render_selection_card

    monkeypatch.chdir(tmp_path)
    assert main(["filter", str(small_darkroom.root), "--out", "sel", "--no-progress"]) == 0
    card = (tmp_path / "sel" / "README.md").read_text()
    line = next(x for x in card.splitlines() if x.startswith("lhf train"))
    assert f"--dataset {small_darkroom.root.resolve()}" in line  # the recorded source, runnable
    # as written, plus the flags that keep a test short (they override none of the written ones)
    args = shlex.split(line)[1:] + ["--preset", "tiny", "--max-steps", "2", "--batch-size", "4"]
    assert main(args) == 0
    assert (tmp_path / "runs" / "ad-lhf" / "model.safetensors").exists()
    snippet = re.findall(r"```python\n(.*?)```", card, flags=re.S)[0]
    exec(snippet, {})  # noqa: S102 - the card's own snippet, as a user would paste it

    pushed = render_selection_card(tmp_path / "sel", load_path="org/sel")
    assert str(small_darkroom.root.resolve()) not in pushed and str(tmp_path) not in pushed
    assert "--dataset DATASET --selection org/sel" in pushed
    assert f"local dataset `{small_darkroom.root.name}`" in pushed
