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
