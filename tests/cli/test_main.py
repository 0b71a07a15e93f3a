"""``lhf`` as a program: an interrupt it has handled is its last (the exit is not cut short)."""

import signal
import sys

import pytest

from lhf_hf.cli import envs
from lhf_hf.cli.main import main
from lhf_hf.utils.signals import Terminated


@pytest.fixture
def handlers():
    """The test process's SIGINT/SIGTERM handlers, put back afterwards."""
    held = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    yield held
    for sig, handler in held.items():
        signal.signal(sig, handler)


@pytest.mark.parametrize(
    ("interrupt", "code"),
    [(KeyboardInterrupt(), 130), (Terminated(128 + signal.SIGTERM), 143)],
)
def test_the_program_ignores_interrupts_once_it_handled_one(
    monkeypatch, handlers, capsys, interrupt, code
):
    def interrupted(args):
        raise interrupt

    monkeypatch.setattr(envs, "run", interrupted)
    monkeypatch.setattr(sys, "argv", ["lhf", "envs"])
    assert main() == code
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
    assert "lhf envs: " in capsys.readouterr().err


def test_main_called_with_argv_leaves_signals_alone(monkeypatch, handlers, capsys):
    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(envs, "run", interrupted)
    assert main(["envs"]) == 130
    assert signal.getsignal(signal.SIGINT) is handlers[signal.SIGINT]
    assert signal.getsignal(signal.SIGTERM) is handlers[signal.SIGTERM]
    assert "lhf envs: interrupted" in capsys.readouterr().err
