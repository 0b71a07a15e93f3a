"""The output-folder policy: what a command may do with the folder it writes."""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
import textwrap

import pytest

from lhf_hf.utils.io import write_text_atomic
from lhf_hf.utils.outputs import MARKER, OutputError, output_folder


def _files(path):
    return sorted(p.name for p in path.iterdir())


def test_new_and_empty_folders_are_claimed_and_marked(tmp_path):
    with output_folder(tmp_path / "a" / "b", "selection") as out:
        (out / "x.txt").write_text("1")
    assert json.loads((out / MARKER).read_text())["kind"] == "selection"
    (tmp_path / "empty").mkdir()
    with output_folder(tmp_path / "empty", "model"):
        pass


def test_someone_elses_folder_is_never_written_or_deleted(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("precious")
    for kw in ({}, {"overwrite": True}, {"resume": True}):
        with pytest.raises(OutputError, match=r"holds 1 entry \(thesis.tex\), not an lhf model"):
            with output_folder(mine, "model", **kw):
                pytest.fail("the body must not run")
    assert _files(mine) == ["thesis.tex"] and (mine / "thesis.tex").read_text() == "precious"


def test_an_artifact_of_another_kind_is_refused(tmp_path):
    with output_folder(tmp_path / "d", "dataset") as d:
        (d / "data.parquet").write_text("rows")
    with pytest.raises(OutputError, match="holds an lhf dataset, not an lhf model"):
        with output_folder(d, "model", overwrite=True):
            pass
    assert (d / "data.parquet").read_text() == "rows"


def test_same_kind_needs_resume_or_overwrite(tmp_path):
    with output_folder(tmp_path / "m", "model") as m:
        (m / "w").write_text("old")
    with pytest.raises(OutputError, match="pass --resume to continue it or --overwrite"):
        with output_folder(m, "model", resumable=True):
            pass
    with pytest.raises(OutputError, match="pass --overwrite to replace it"):
        with output_folder(m, "model"):
            pass
    with output_folder(m, "model", resume=True):
        assert (m / "w").read_text() == "old"
    with output_folder(m, "model", overwrite=True):
        assert _files(m) == [MARKER]  # a fresh folder under the name
        (m / "w").write_text("new")
    assert (m / "w").read_text() == "new"
    assert not list(tmp_path.glob(".m.replaced-*"))  # the old one is gone once the new is done


def test_unmarked_folders_are_resumed_at_most_never_replaced(tmp_path):
    """Files that look like an older artifact (config.json, checkpoint-*) may be someone's own
    model: resumed when asked, never deleted."""
    ck = tmp_path / "ck"
    ck.mkdir()
    (ck / "checkpoint-4").mkdir()
    (ck / "weights.bin").write_text("theirs")
    with pytest.raises(OutputError, match="has no .lhf_output.json .* refusing to replace it"):
        with output_folder(ck, "model", overwrite=True, legacy=["checkpoint-*"]):
            pass
    assert (ck / "weights.bin").read_text() == "theirs"
    with output_folder(ck, "model", resume=True, legacy=["checkpoint-*"]):
        pass


def test_a_refused_run_leaves_an_existing_folder_as_it_was(tmp_path):
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "config.json").write_text("{}")
    with pytest.raises(RuntimeError):
        with output_folder(theirs, "model", resume=True, legacy=["config.json"]):
            raise RuntimeError("not our format after all")
    assert _files(theirs) == ["config.json"]  # no marker stamped into it
    with output_folder(tmp_path / "m", "model") as m:
        (m / "w").write_text("w")
    manifest = (m / MARKER).read_text()
    with pytest.raises(RuntimeError):
        with output_folder(m, "model", resume=True):
            raise RuntimeError("refused before writing")
    assert (m / MARKER).read_text() == manifest  # still complete, still verifiable


def test_a_symlinked_output_is_its_target(tmp_path):
    with output_folder(tmp_path / "real", "model") as real:
        (real / "w").write_text("old")
    (tmp_path / "link").symlink_to(real)
    with output_folder(tmp_path / "link", "model", overwrite=True) as got:
        assert got == real.resolve()
        (got / "w").write_text("new")
    assert (tmp_path / "link").is_symlink() and (real / "w").read_text() == "new"
    assert not list(tmp_path.glob(".*replaced*"))


def test_lock_files_are_not_content(tmp_path):
    m = tmp_path / "m"
    with pytest.raises(ValueError):
        with output_folder(m / "eval", "evaluation"):
            assert sorted(p.name for p in m.iterdir()) == [".eval.lock", "eval"]
            raise ValueError("bad model")
    assert list(m.iterdir()) == []  # the lock file goes with the writer, also after an error
    (m / ".eval.lock").write_text("12345\n")  # as a killed writer leaves it
    with output_folder(m, "model"):  # m holds only a lock file: empty
        pass
    with output_folder(m / "eval", "evaluation"):  # a killed writer's lock file is taken over
        pass
    assert not list(m.glob(".*.lock"))


def test_a_failed_overwrite_puts_the_old_artifact_back(tmp_path):
    with output_folder(tmp_path / "m", "model") as m:
        (m / "w").write_text("old")
    for error in (RuntimeError("boom"), KeyboardInterrupt()):
        with pytest.raises(type(error)):
            with output_folder(m, "model", overwrite=True):
                (m / "w").write_text("half-written")
                raise error
        assert (m / "w").read_text() == "old"
        assert not list(tmp_path.glob(".m.replaced-*"))


def test_a_failed_overwrite_whose_old_artifact_was_deleted_keeps_its_own_error(tmp_path, capsys):
    with output_folder(tmp_path / "m", "model") as m:
        (m / "w").write_text("old")
    with pytest.raises(KeyboardInterrupt):  # not a FileNotFoundError from putting it back
        with output_folder(m, "model", overwrite=True):
            (m / "w").write_text("half-written")
            for aside in tmp_path.glob(".m.replaced-*"):  # deleted by hand mid-run
                shutil.rmtree(aside)
            raise KeyboardInterrupt
    assert "was removed while this run wrote" in capsys.readouterr().err
    assert (m / "w").read_text() == "half-written"  # this run's part stays, marked in progress
    assert "files" not in json.loads((m / MARKER).read_text())
    with output_folder(m, "model", resume=True):
        pass


def test_an_overwrite_of_a_marker_only_folder_sets_nothing_aside(tmp_path):
    out = tmp_path / "r"
    out.mkdir()
    (out / MARKER).write_text(json.dumps({"kind": "report", "lhf_hf": "0"}))  # a run killed early
    with output_folder(out, "report", overwrite=True) as r:
        assert not list(tmp_path.glob(".r.replaced-*"))
        (r / "report.md").write_text("new")
    assert _files(out) == [MARKER, "report.md"] and not list(tmp_path.glob(".r.replaced-*"))
    # a finished artifact that happens to hold no files is set aside and put back as before
    empty = tmp_path / "e"
    with output_folder(empty, "report"):
        pass
    done = (empty / MARKER).read_text()
    with pytest.raises(KeyboardInterrupt):
        with output_folder(empty, "report", overwrite=True) as r:
            assert list(tmp_path.glob(".e.replaced-*"))
            (r / "report.md").write_text("half")
            raise KeyboardInterrupt
    assert _files(empty) == [MARKER] and (empty / MARKER).read_text() == done


def test_an_aside_name_left_by_an_earlier_process_with_our_pid_is_not_reused(tmp_path):
    with output_folder(tmp_path / "m", "model") as m:
        (m / "w").write_text("old")
    stale = tmp_path / f".m.replaced-{os.getpid()}"  # a killed run's, before a restart
    stale.mkdir()
    (stale / "w").write_text("older")
    with output_folder(m, "model", overwrite=True):
        (m / "w").write_text("new")
    assert (m / "w").read_text() == "new" and (stale / "w").read_text() == "older"


def test_a_failure_before_writing_leaves_no_folder(tmp_path):
    with pytest.raises(ValueError):
        with output_folder(tmp_path / "new", "evaluation"):
            raise ValueError("bad model")
    assert not (tmp_path / "new").exists()


def test_an_interrupted_first_run_stays_an_artifact_in_progress(tmp_path):
    """A folder a run started empty (made by it, or given empty) and wrote into before failing
    keeps its in-progress marker: --resume continues it and --overwrite replaces it.  Without the
    marker both refused it as someone's files, and a rerun of `lhf reproduce` was stuck."""
    (tmp_path / "given").mkdir()
    for name in ("made", "given"):
        out = tmp_path / name
        with pytest.raises(KeyboardInterrupt):
            with output_folder(out, "dataset"):
                (out / "part-0").write_text("half")
                raise KeyboardInterrupt
        assert json.loads((out / MARKER).read_text()) == {
            "kind": "dataset",
            "lhf_hf": json.loads((out / MARKER).read_text())["lhf_hf"],
        }  # no manifest: not a finished artifact
        with pytest.raises(OutputError, match="--resume to continue it or --overwrite"):
            with output_folder(out, "dataset", resumable=True):
                pass
        with output_folder(out, "dataset", resume=True):
            assert (out / "part-0").read_text() == "half"
        with output_folder(out, "dataset", overwrite=True):
            assert _files(out) == [MARKER]
    # failing before writing anything: an empty folder given to it is left empty
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError):
        with output_folder(tmp_path / "empty", "evaluation"):
            raise ValueError("bad model")
    assert _files(tmp_path / "empty") == []


def test_inputs_are_never_the_output_or_inside_it(tmp_path):
    src = tmp_path / "data"
    with output_folder(src, "dataset"):
        (src / "f").write_text("data")
    with pytest.raises(OutputError, match=r"output folder .*data is the input"):
        with output_folder(src, "dataset", overwrite=True, inputs=[src]):
            pass
    with pytest.raises(OutputError, match="contains the input"):
        with output_folder(tmp_path, "dataset", overwrite=True, inputs=[str(src)]):
            pass
    # inside an input is allowed (lhf evaluate --model m --out m/eval); Hub ids are skipped
    model = tmp_path / "model"
    with output_folder(model, "model"):
        (model / "w").write_text("weights")
    with output_folder(model / "eval", "evaluation", inputs=[model, "org/name", None]):
        pass
    assert (src / "f").read_text() == "data" and (model / "w").read_text() == "weights"


def test_a_file_is_not_a_folder(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputError, match="is a file, not a folder"):
        with output_folder(tmp_path / "f", "model"):
            pass


def test_an_output_under_a_file_is_a_clear_error(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputError, match="cannot write the output folder .*sub: File exists"):
        with output_folder(tmp_path / "f" / "sub", "model"):
            pass


def test_unwritable_parent_is_a_clear_error(tmp_path):
    if os.geteuid() == 0:
        pytest.skip("root writes anywhere")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(OutputError):
            with output_folder(ro / "out", "model"):
                pass
    finally:
        ro.chmod(0o700)


def test_a_second_writer_is_refused_naming_the_holder(tmp_path):
    """A real second process holds the folder; this one gets an error with that PID."""
    out = tmp_path / "busy"
    code = textwrap.dedent(
        f"""
        import sys, time
        from lhf_hf.utils.outputs import output_folder
        with output_folder({str(out)!r}, "model"):
            print("held", flush=True)
            sys.stdin.readline()
        """
    )
    holder = subprocess.Popen(
        [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(
            OutputError, match=f"being written by another process \\(PID {holder.pid}\\)"
        ):
            with output_folder(out, "model", overwrite=True):
                pass
    finally:
        holder.communicate("\n", timeout=60)
    assert not (tmp_path / ".busy.lock").exists()  # the holder deleted its lock file
    with output_folder(out, "model", overwrite=True):  # free again once the holder is done
        pass
    assert _files(tmp_path) == ["busy"]


def test_killed_overwrite_keeps_the_old_artifact_beside(tmp_path):
    """kill -9 during an overwrite: the old artifact survives whole, and the next writer names it."""
    out = tmp_path / "m"
    with output_folder(out, "model") as m:
        (m / "w").write_text("old")
    code = textwrap.dedent(
        f"""
        import sys
        from lhf_hf.utils.outputs import output_folder
        with output_folder({str(out)!r}, "model", overwrite=True) as m:
            (m / "w").write_text("half")
            print("writing", flush=True)
            sys.stdin.readline()
        """
    )
    p = subprocess.Popen(
        [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    assert p.stdout.readline().strip() == "writing"
    p.kill()
    p.wait(timeout=60)
    (kept,) = tmp_path.glob(".m.replaced-*")
    assert (kept / "w").read_text() == "old"
    code = f"from lhf_hf.utils.outputs import output_folder\nwith output_folder({str(out)!r}, 'model', resume=True): pass"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert str(kept) in r.stderr and "interrupted --overwrite" in r.stderr
    assert "complete (its manifest checks)" in r.stderr and f"mv {kept} {out}" in r.stderr


def test_atomic_writes_follow_the_umask(tmp_path):
    write_text_atomic("x", tmp_path / "a.txt")
    mode = stat.S_IMODE((tmp_path / "a.txt").stat().st_mode)
    umask = os.umask(0)
    os.umask(umask)
    assert mode == 0o666 & ~umask


def test_overwrite_refuses_what_the_artifact_did_not_write(tmp_path):
    """Files added after the artifact was written and nested artifacts (``--out MODEL/eval``) are
    named and never deleted; the artifact's own files are replaced as before."""
    with output_folder(tmp_path / "m", "model", mutable=["README.md"]) as m:
        (m / "w").write_text("old")
        (m / "README.md").write_text("card")
    (m / "README.md").write_text("card, updated by an evaluation")  # mutable: still the model's
    with output_folder(m / "eval", "evaluation") as ev:
        (ev / "eval_results.json").write_text("{}")
    (m / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match=r"2 entries its model did not write \(eval/ \(an lhf "
                       r"evaluation\), notes.txt\)"):  # fmt: skip
        with output_folder(m, "model", overwrite=True):
            pytest.fail("the body must not run")
    assert (m / "notes.txt").read_text() == "mine" and (ev / "eval_results.json").exists()
    shutil.rmtree(ev)
    (m / "notes.txt").unlink()
    with output_folder(m, "model", overwrite=True) as new:
        (new / "w").write_text("new")
    assert (m / "w").read_text() == "new"


def test_an_interrupt_after_the_body_puts_the_old_artifact_back(tmp_path, capsys):
    with output_folder(tmp_path / "s", "selection") as s:
        (s / "x").write_text("old")
    with pytest.raises(KeyboardInterrupt):
        with output_folder(s, "selection", overwrite=True) as new:
            (new / "x").write_text("new")
            raise KeyboardInterrupt  # the new copy is whole; the switch has not begun
    assert (s / "x").read_text() == "old" and not list(tmp_path.glob(".s.replaced-*"))
    assert "holds the earlier selection again (unchanged)" in capsys.readouterr().err


def test_an_interrupt_during_the_switch_is_held_off(tmp_path, monkeypatch, handlers):
    """Ctrl-C while the manifest is written and the old copy deleted: the switch completes (the
    new artifact whole, no half-deleted aside), then the interrupt is delivered."""
    import signal

    import lhf_hf.utils.outputs as outputs

    # Python's own Ctrl-C handler, even where the suite was started with SIGINT ignored (a shell's
    # background job: then Python leaves SIG_IGN in place and no interrupt is ever delivered)
    signal.signal(signal.SIGINT, signal.default_int_handler)

    with output_folder(tmp_path / "s", "selection") as s:
        (s / "x").write_text("old")
    real_record = outputs.record_manifest

    def record_then_interrupt(*args, **kwargs):
        signal.raise_signal(signal.SIGINT)  # held within the switch (to this thread: no delivery race)
        real_record(*args, **kwargs)

    monkeypatch.setattr(outputs, "record_manifest", record_then_interrupt)
    with pytest.raises(KeyboardInterrupt):  # delivered once the switch is done
        with output_folder(s, "selection", overwrite=True) as new:
            (new / "x").write_text("new")
    assert (s / "x").read_text() == "new" and not list(tmp_path.glob(".s.replaced-*"))
    assert "files" in json.loads((s / MARKER).read_text())
    assert outputs.COMPLETED[-1] == ("selection", s.resolve())  # what main names as completed


def test_an_output_inside_an_input_dataset_is_refused(tmp_path):
    with output_folder(tmp_path / "d", "dataset") as d:
        (d / "data.parquet").write_text("rows")
    with pytest.raises(OutputError, match="is inside the input dataset"):
        with output_folder(d / "data" / "sel", "selection", inputs=[d]):
            pytest.fail("the body must not run")
    assert _files(d) == [MARKER, "data.parquet"]
    with output_folder(tmp_path / "m", "model") as m:  # inside a model: fine (MODEL/eval)
        (m / "w").write_text("1")
    with output_folder(m / "eval", "evaluation", inputs=[m]):
        pass


def test_overwriting_an_unfinished_artifact_keeps_it_beside(tmp_path, capsys):
    """An unfinished folder has no manifest: files a user added to it cannot be told from the
    command's, so an overwrite keeps the old folder beside the new one and names it."""
    out = tmp_path / "d"
    with pytest.raises(RuntimeError):
        with output_folder(out, "dataset") as d:
            (d / "part.parquet").write_text("half")
            raise RuntimeError("killed")
    (out / "mine.txt").write_text("mine")
    with output_folder(out, "dataset", overwrite=True) as d:
        (d / "data.parquet").write_text("new")
    (kept,) = tmp_path.glob(".d.unfinished-*")
    assert (kept / "mine.txt").read_text() == "mine" and _files(out) == [MARKER, "data.parquet"]
    assert f"is kept at {kept}" in capsys.readouterr().err


def test_hidden_files_and_empty_folders_are_not_the_commands(tmp_path):
    """The manifest never lists hidden names or empty folders, so they are checked apart: an
    overwrite refuses a user's .notes, .git or empty folder instead of deleting it."""
    with output_folder(tmp_path / "m", "model") as m:
        (m / "w").write_text("old")
    for extra in (".notes", ".git/HEAD", "mydir/"):
        target = m / extra
        if extra.endswith("/"):
            target.mkdir()
        else:
            target.parent.mkdir(exist_ok=True)
            target.write_text("mine")
        with pytest.raises(OutputError, match="did not write"):
            with output_folder(m, "model", overwrite=True):
                pytest.fail("the body must not run")
        assert target.exists()
        shutil.rmtree(target) if target.is_dir() else target.unlink()
        if extra == ".git/HEAD":
            (m / ".git").rmdir()
    with output_folder(m, "model", overwrite=True) as new:  # our own hidden files are ours
        (new / "w").write_text("new")
