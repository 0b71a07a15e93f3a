"""``utils.signals``: SIGTERM as an exception; a program's interrupts raise once, then are ignored."""

import os
import signal
import time

import pytest

from lhf_hf.utils.signals import Terminated, interrupts_raise_once, sigterm_raises


def _wait_for_signal() -> None:
    time.sleep(5)  # a delivered signal's handler runs here, in the main thread
    raise AssertionError("the signal was not raised")


@pytest.mark.parametrize(
    ("first", "raised"), [(signal.SIGINT, KeyboardInterrupt), (signal.SIGTERM, Terminated)]
)
def test_the_first_interrupt_raises_and_later_ones_are_ignored(handlers, first, raised):
    interrupts_raise_once()
    with pytest.raises(raised) as info:
        os.kill(os.getpid(), first)
        _wait_for_signal()
    if raised is Terminated:
        assert info.value.code == 128 + signal.SIGTERM
    # the cleanup that follows is not cut short: neither signal raises, nor ends the process
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGINT):
        os.kill(os.getpid(), sig)
    time.sleep(0.2)
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN


def test_sigterm_raises_within_the_block_only(handlers):
    with pytest.raises(Terminated) as info, sigterm_raises():
        os.kill(os.getpid(), signal.SIGTERM)
        _wait_for_signal()
    assert info.value.code == 128 + signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) is handlers[signal.SIGTERM]
