"""``lhf`` as a program: the first interrupt stops the command, later ones are ignored."""

import os
import signal
import sys
import time

import pytest

from lhf_hf.cli import envs
from lhf_hf.cli.main import main


def _pressed(signum, cleaned):
    """A command that gets ``signum``, then again and again while it cleans up."""

    def run(args):
        try:
            os.kill(os.getpid(), signum)
            time.sleep(5)
        finally:
            for sig in (signal.SIGINT, signal.SIGTERM):
                os.kill(os.getpid(), sig)
            time.sleep(0.2)  # a handler would raise here, and cut the cleanup short
            cleaned.append(True)

    return run


@pytest.mark.parametrize(("signum", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_the_program_cleans_up_whole_however_often_it_is_interrupted(
    monkeypatch, handlers, capsys, signum, code
):
    cleaned = []
    monkeypatch.setattr(envs, "run", _pressed(signum, cleaned))
    monkeypatch.setattr(sys, "argv", ["lhf", "envs"])
    assert main() == code
    assert cleaned == [True]
    # ... and its exit ignores them too (the interpreter's exit puts SIGINT's default back)
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
    word = "interrupted" if signum == signal.SIGINT else "terminated"
    assert f"lhf envs: {word}" in capsys.readouterr().err


def test_main_called_with_argv_leaves_signals_as_they_were(monkeypatch, handlers, capsys):
    def terminated(args):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)

    monkeypatch.setattr(envs, "run", terminated)
    assert main(["envs"]) == 143
    assert signal.getsignal(signal.SIGINT) is handlers[signal.SIGINT]
    assert signal.getsignal(signal.SIGTERM) is handlers[signal.SIGTERM]
    assert "lhf envs: terminated" in capsys.readouterr().err


def test_what_the_machine_refuses_is_one_line(tmp_path, capsys):
    """Too much memory asked, a name too long, a malformed file: one line naming it, exit 1."""
    out = tmp_path / "d"
    assert main(["collect", "darkroom", "--out", str(out), "--tasks", "3", "--histories", "4",
                 "--steps", "1000000000000", "--collector", "batched", "--no-progress"]) == 1  # fmt: skip
    err = capsys.readouterr().err
    assert "not enough memory for what was asked" in err and "Traceback" not in err
    assert main(["collect", "darkroom", "--out", str(tmp_path / ("x" * 300)), "--tasks", "3"]) == 1
    err = capsys.readouterr().err
    assert "File name too long" in err and "Traceback" not in err
    assert main(["filter", str(out), "--out", str(tmp_path / "s"), "--lam", "1e308"]) == 1
    assert "lam must be between 0 and 1e+06" in capsys.readouterr().err
    model = tmp_path / "m"
    model.mkdir()
    (model / "config.json").write_text("{not json")
    assert main(["evaluate", "--model", str(model), "--out", str(tmp_path / "e")]) == 1
    assert f"{model / 'config.json'} is not a readable model config" in capsys.readouterr().err


@pytest.mark.parametrize(("signum", "code", "word"), [(signal.SIGINT, 130, "interrupted"),
                                                       (signal.SIGTERM, 143, "terminated")])  # fmt: skip
def test_an_interrupt_a_library_wrapped_is_still_an_interrupt(
    monkeypatch, handlers, capsys, signum, code, word
):
    """transformers' lazy import turns a KeyboardInterrupt into "Could not import module ...":
    the program was interrupted, and says so (not "error: Could not import ...", exit 1)."""
    from lhf_hf.utils import signals

    monkeypatch.setattr(signals, "_received", [])

    def run(args):
        try:
            os.kill(os.getpid(), signum)
            time.sleep(5)
        except BaseException as exc:
            raise RuntimeError("Could not import module 'LlamaModel'") from exc

    monkeypatch.setattr(envs, "run", run)
    monkeypatch.setattr(sys, "argv", ["lhf", "envs"])
    assert main() == code
    err = capsys.readouterr().err
    assert f"lhf envs: {word}" in err and "Could not import" not in err


@pytest.mark.slow
@pytest.mark.parametrize(
    "argv",
    [
        ["envs", "--json"],  # a command's output
        ["--help"],  # argparse's, written at parsing and flushed only at exit
        ["train", "--help"],  # larger than the pipe's buffer
        ["--version"],
        [],  # no command: the help, and the usage's status
    ],
)
def test_a_closed_pipe_ends_quietly(tmp_path, argv):
    """`lhf envs --json | head -1`, `lhf --help | head -1`: no BrokenPipeError traceback (nor
    Python's "Exception ignored" at exit), the status of a shell tool killed by SIGPIPE."""
    import subprocess

    read, write = os.pipe()
    os.close(read)  # the reader went away before the program writes anything
    # buffered as in a shell (PYTHONUNBUFFERED would write at once and hide the exit's flush)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    p = subprocess.run([sys.executable, "-m", "lhf_hf", *argv], stdout=write, env=env,
                       stderr=subprocess.PIPE, text=True, timeout=120)  # fmt: skip
    os.close(write)
    assert p.returncode == 128 + signal.SIGPIPE and p.stderr == "", p.stderr


@pytest.mark.slow
def test_a_file_missing_a_field_is_named_as_such(small_darkroom, tmp_path, capsys):
    import json

    sel = tmp_path / "sel"
    assert main(["filter", str(small_darkroom.root), "--out", str(sel), "--no-progress"]) == 0
    conf = sel / "filter_config.json"
    conf.write_text(
        json.dumps({k: v for k, v in json.loads(conf.read_text()).items() if k != "source"})
    )
    assert main(["train", "--dataset", str(small_darkroom.root), "--selection", str(sel),
                 "--objective", "ad", "--preset", "tiny", "--max-steps", "1", "--batch-size", "4",
                 "--out", str(tmp_path / "m")]) == 1  # fmt: skip
    err = capsys.readouterr().err
    assert "has no 'source' object" in err and "Traceback" not in err


@pytest.mark.parametrize("command", [["filter", "d", "--out", "s"], ["evaluate", "--model", "m", "--out", "e"],
                                     ["train", "--dataset", "d", "--objective", "ad", "--out", "m"]])  # fmt: skip
def test_a_negative_seed_names_its_flag(command, capsys):
    assert main([*command, "--seed", "-1"]) == 1
    assert "seed must be >= 0, got -1" in capsys.readouterr().err


def _raising(exc):
    def run(args):
        raise exc

    return run


def test_an_expected_failure_is_one_line_and_a_bug_keeps_its_traceback(monkeypatch, capsys):
    """UserError (and its kinds) -> one line, exit 1; a KeyError or TypeError of our own code is a
    bug: it propagates with its traceback instead of posing as bad input."""
    from lhf_hf.errors import NotFoundError, UnknownNameError, UserError

    for exc, line in [
        (UserError("histories must be >= 1, got 0"), "histories must be >= 1, got 0"),
        (NotFoundError("no dataset folder at d"), "no dataset folder at d"),
        (UnknownNameError("unknown env id 'x'"), "unknown env id 'x'"),  # not KeyError's quotes
    ]:
        monkeypatch.setattr(envs, "run", _raising(exc))
        assert main(["envs"]) == 1
        err = capsys.readouterr().err
        assert err == f"lhf envs: error: {line}\n", err
    for bug in [KeyError("window_size"), TypeError("f() got an unexpected keyword"), IndexError(3)]:
        monkeypatch.setattr(envs, "run", _raising(bug))
        with pytest.raises(type(bug)):
            main(["envs"])


def test_lhf_debug_shows_the_traceback_of_an_expected_failure(monkeypatch, capsys):
    from lhf_hf.errors import UserError

    monkeypatch.setattr(envs, "run", _raising(UserError("bad value")))
    monkeypatch.setenv("LHF_DEBUG", "1")
    assert main(["envs"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and err.endswith("lhf envs: error: bad value\n")


def test_a_field_missing_from_a_file_names_the_file(tmp_path):
    from lhf_hf.errors import MissingFieldError, UserError
    from lhf_hf.utils.io import read_json

    (tmp_path / "info.json").write_text('{"a": {"b": 1}, "c": [{"d": 2}]}')
    record = read_json(tmp_path / "info.json")
    assert record == {"a": {"b": 1}, "c": [{"d": 2}]} and record.get("x") is None
    for get in (lambda r: r["x"], lambda r: r["a"]["y"], lambda r: r["c"][0]["z"]):
        with pytest.raises(MissingFieldError, match=r"info.json has no field '[xyz]'") as info:
            get(record)
        assert isinstance(info.value, UserError) and isinstance(info.value, KeyError)
