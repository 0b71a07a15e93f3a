"""The commands never delete or write into what they do not own (issue cases, from the CLI)."""

from __future__ import annotations

import shutil

import pytest

from lhf_hf.cli.main import main
from tests.trees import tree_digest


@pytest.fixture()
def data(small_darkroom_batched, tmp_path):
    """A private copy of the small dataset (the commands below try to destroy it)."""
    root = tmp_path / "data"
    shutil.copytree(small_darkroom_batched.root, root)
    return root


TRAIN = ["--objective", "ad", "--preset", "tiny", "--max-steps", "2", "--batch-size", "2"]


def test_train_overwrite_never_deletes_a_dataset_or_someone_elses_folder(data, tmp_path, capsys):
    before = tree_digest(data)
    assert main(["train", "--dataset", str(data), "--out", str(data), "--overwrite", *TRAIN]) == 1
    assert "is the input" in capsys.readouterr().err
    other = tmp_path / "other"
    shutil.copytree(data, other)
    assert main(["train", "--dataset", str(data), "--out", str(other), "--overwrite", *TRAIN]) == 1
    assert "holds an lhf dataset, not an lhf model" in capsys.readouterr().err
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.md").write_text("mine")
    assert main(["train", "--dataset", str(data), "--out", str(mine), "--overwrite", *TRAIN]) == 1
    assert "not an lhf model: refusing to replace it" in capsys.readouterr().err
    assert (mine / "notes.md").read_text() == "mine" and len(list(mine.iterdir())) == 1
    assert tree_digest(data) == before


def test_filter_and_derive_never_replace_their_source(data, tmp_path, capsys):
    before = tree_digest(data)
    sel = str(tmp_path / "sel")
    assert main(["filter", str(data), "--out", sel, "--materialize", str(data), "--overwrite"]) == 1
    assert "is the input" in capsys.readouterr().err
    assert main(["derive", "half", str(data), "--out", str(data), "--overwrite"]) == 1
    assert "is the input" in capsys.readouterr().err
    assert main(["derive", "half", str(data), "--out", str(tmp_path), "--overwrite"]) == 1
    assert "contains the input" in capsys.readouterr().err
    assert tree_digest(data) == before


@pytest.mark.slow
def test_existing_outputs_need_overwrite(data, tmp_path, capsys):
    # a folder with someone's README: filter neither writes into it nor replaces it
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "README.md").write_text("my notes")
    assert main(["filter", str(data), "--out", str(mine)]) == 1
    assert "not an lhf selection: refusing to write into it" in capsys.readouterr().err
    assert (mine / "README.md").read_text() == "my notes"
    # a selection of ours: replaced only with --overwrite
    sel = str(tmp_path / "sel")
    assert main(["filter", str(data), "--out", sel]) == 0
    capsys.readouterr()
    assert main(["filter", str(data), "--out", sel, "--lam", "0"]) == 1
    assert "already holds an lhf selection: pass --overwrite" in capsys.readouterr().err
    assert main(["filter", str(data), "--out", sel, "--lam", "0", "--overwrite"]) == 0
    # evaluate: earlier results are not silently replaced
    model = str(tmp_path / "m")
    assert main(["train", "--dataset", str(data), "--out", model, *TRAIN]) == 0
    ev = [
        "evaluate",
        "--model",
        model,
        "--episodes",
        "1",
        "--tasks",
        "38",
        "--out",
        f"{model}/eval",
    ]
    assert main(ev) == 0
    capsys.readouterr()
    assert main(ev) == 1
    assert "already holds an lhf evaluation: pass --overwrite" in capsys.readouterr().err
    assert main([*ev, "--overwrite"]) == 0
    # compare into an existing comparison: --overwrite again (a copy of the run stands in
    # for a second run: compare refuses one run on both sides)
    shutil.copytree(f"{model}/eval", f"{model}/eval2")
    cmp = [
        "compare",
        "--baseline",
        f"{model}/eval",
        "--lhf",
        f"{model}/eval2",
        "--out",
        str(tmp_path / "c"),
    ]
    assert main(cmp) == 0
    assert main(cmp) == 1
    assert main([*cmp, "--overwrite"]) == 0


def test_a_file_as_out_is_one_clear_line(data, tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["filter", str(data), "--out", str(f)]) == 1
    err = capsys.readouterr().err
    assert "is a file, not a folder" in err and "Traceback" not in err


def test_a_refused_materialize_writes_no_selection(data, tmp_path, capsys):
    sel = tmp_path / "sel"
    assert (
        main(["filter", str(data), "--out", str(sel), "--materialize", str(data), "--overwrite"])
        == 1
    )
    assert "is the input" in capsys.readouterr().err
    assert not sel.exists()


def test_an_existing_materialize_folder_names_only_flags_filter_has(data, tmp_path, capsys):
    mat = tmp_path / "mat"
    assert (
        main(["filter", str(data), "--out", str(tmp_path / "s1"), "--materialize", str(mat)]) == 0
    )
    assert (
        main(["filter", str(data), "--out", str(tmp_path / "s2"), "--materialize", str(mat)]) == 1
    )
    err = capsys.readouterr().err
    assert "pass --overwrite to replace it" in err and "--resume" not in err


@pytest.mark.slow
def test_sigterm_during_overwrite_puts_the_old_model_back(data, tmp_path):
    """kill -TERM (what `timeout` and `docker stop` send) cleans up like Ctrl-C."""
    import os
    import signal
    import subprocess
    import sys
    import time

    model = tmp_path / "m"
    assert main(["train", "--dataset", str(data), "--out", str(model), *TRAIN]) == 0
    before = tree_digest(model)
    cmd = [sys.executable, "-m", "lhf_hf", "train", "--dataset", str(data), "--out", str(model),
           "--overwrite", "--objective", "ad", "--preset", "tiny", "--max-steps", "100000",
           "--batch-size", "2"]  # fmt: skip
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not list(tmp_path.glob(".m.replaced-*")) and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(2)  # inside training
    os.kill(p.pid, signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 128 + signal.SIGTERM, err[-2000:]
    assert "terminated" in err and "Traceback" not in err
    assert tree_digest(model) == before and not list(tmp_path.glob(".m.replaced-*"))
