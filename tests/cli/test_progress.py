"""``--no-progress`` on every long command: one definition, and every bar off: lhf's own and
Trainer's (the ``progress`` argument of the function the command calls) and the ones transformers,
datasets and huggingface_hub draw themselves (their global switches, put back afterwards)."""

from __future__ import annotations

from pathlib import Path

import datasets
import pytest
from huggingface_hub import utils as hub_utils
from transformers.utils import logging as hf_logging

import lhf_hf.collection
import lhf_hf.evaluation
import lhf_hf.filtering.run
import lhf_hf.histories.derive
import lhf_hf.histories.upgrade
import lhf_hf.hub
import lhf_hf.reproduce
import lhf_hf.training
import lhf_hf.verify
from lhf_hf.cli.main import COMMANDS, build_parser, main
from lhf_hf.utils.progress import library_bars


def _bars() -> tuple[bool, bool, bool]:
    """Whether transformers, datasets and huggingface_hub would draw their bars now."""
    return (
        hf_logging.is_progress_bar_enabled(),
        datasets.is_progress_bar_enabled(),
        not hub_utils.are_progress_bars_disabled(),
    )


EVAL = {"env_id": "darkroom", "tasks": [0], "mean_return": 0.0, "first_return": 0.0,
        "final_return": 0.0, "success_rate": None, "env_steps_per_s": 1.0,
        "task_label": "unseen tasks"}  # fmt: skip
PUSHED = {"kind": "dataset", "repo_type": "dataset", "commit": "0" * 40}
VERIFIED = {"notes": [], "problems": [], "path": "p", "kind": "dataset"}

#: command line (without --no-progress), where its work is done, what that returns, and whether it
#: takes ``progress`` (the commands whose bars are all the libraries' do not)
CASES = {
    "collect": (["darkroom", "--tasks", "0", "--out", "o"], (lhf_hf.collection, "collect"), None,
                True),
    "derive": (["half", "src", "--out", "o"], (lhf_hf.histories.derive.DERIVATIONS, "half"), "ds",
               True),
    "filter": (["d", "--out", "o"], (lhf_hf.filtering.run, "run_filter"), {}, True),
    "train": (["--dataset", "d", "--objective", "ad", "--out", "o"], (lhf_hf.training, "train"),
              Path("o"), True),
    "evaluate": (["--model", "m", "--out", "o"], (lhf_hf.evaluation, "evaluate"), EVAL, True),
    "compare": (["--baseline", "a", "--lhf", "b"], (lhf_hf.evaluation, "compare"), {"table": ""},
                False),
    "push": (["p", "--repo-id", "org/name"], (lhf_hf.hub, "push"), PUSHED, False),
    "reproduce": (["darkroom-main"], (lhf_hf.reproduce, "reproduce"), None, True),
    "verify": (["p"], (lhf_hf.verify, "verify"), VERIFIED, False),
    "upgrade": (["p"], (lhf_hf.histories.upgrade, "upgrade"), None, False),
}  # fmt: skip


def test_every_long_command_has_the_flag():
    """Every command but the two that print at once (envs, accelerate-config) takes it."""
    parser = build_parser()
    names = {m.add_parser.__module__.rsplit(".", 1)[1].replace("_", "-") for m in COMMANDS}
    assert set(CASES) == names - {"envs", "accelerate-config"}
    for command, (argv, *_) in CASES.items():
        assert parser.parse_args([command, *argv, "--no-progress"]).progress is False
        assert not hasattr(parser.parse_args([command, *argv]), "progress")  # the default: on


@pytest.mark.parametrize("command", list(CASES))
def test_no_progress_turns_every_bar_off(monkeypatch, capsys, command):
    argv, (owner, name), result, takes_progress = CASES[command]
    seen = []

    def work(*args, **kwargs):
        seen.append((kwargs.get("progress"), _bars()))
        return result

    if isinstance(owner, dict):
        monkeypatch.setitem(owner, name, work)
    else:
        monkeypatch.setattr(owner, name, work)
    before = _bars()
    assert before == (True, True, True)  # the test starts with the libraries' defaults
    assert main([command, *argv, "--no-progress"]) == 0, capsys.readouterr().err
    assert main([command, *argv]) == 0, capsys.readouterr().err
    off, on = seen
    assert off == (False if takes_progress else None, (False, False, False))
    assert on == (True if takes_progress else None, (True, True, True))
    assert _bars() == before  # put back after the command


def test_library_bars_keep_a_switch_that_was_off_off():
    datasets.disable_progress_bars()
    try:
        with library_bars(False):
            assert _bars() == (False, False, False)
        assert _bars() == (True, False, True)
    finally:
        datasets.enable_progress_bars()
