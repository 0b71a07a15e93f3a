"""Ctrl-C at any instant of an ``--overwrite``: the complete old artifact or the complete new one,
never a mix (issue cases: a materialised dataset that no longer matches its selection, an
evaluation in the card that is not on disk).  Each command is interrupted at delays spread over
its whole run, from start-up to the final switch; the invariant must hold at every one."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest

from lhf_hf.cli.main import main
from lhf_hf.verify import verify
from tests.trees import tree_digest

DELAYS = (0.2, 0.6, 1.0, 1.4, 1.8, 2.2, 2.8, 3.5)


def _interrupt(cmd: list[str], delay: float, cwd) -> tuple[int, str]:
    p = subprocess.Popen(
        [sys.executable, "-m", "lhf_hf", *cmd], cwd=cwd, stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    time.sleep(delay)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=300)
    return p.returncode, err


@pytest.mark.slow
def test_filter_with_materialize_stays_a_pair(small_darkroom_batched, tmp_path):
    data = small_darkroom_batched.root  # only read: no private copy needed
    sel, mat = tmp_path / "sel", tmp_path / "mat"
    first = ["filter", str(data), "--out", str(sel), "--materialize", str(mat), "--no-progress"]
    assert main(first) == 0
    old = tree_digest(sel), tree_digest(mat)
    seen = set()
    for delay in DELAYS:
        cmd = [*first, "--overwrite", "--lam", "0"]
        rc, err = _interrupt(cmd, delay, tmp_path)
        assert "Traceback" not in err, err[-3000:]
        assert not list(tmp_path.glob(".*.replaced-*")), (delay, err)
        if (tree_digest(sel), tree_digest(mat)) == old:
            seen.add("old")
            continue
        # otherwise both are the new ones, complete, and made from each other
        seen.add("new")
        # finished, or interrupted just after the switch: then it says what it had completed
        assert rc == 0 or (rc == 130 and "after it completed the selection" in err), (
            delay,
            rc,
            err,
        )
        assert verify(sel)["problems"] == [] and verify(mat)["problems"] == []
        lam_sel = json.loads((sel / "filter_config.json").read_text())["filter"]["lam"]
        lam_mat = json.loads((mat / "meta" / "lhf_info.json").read_text())["derived_from"]
        assert lam_sel == lam_mat["filter"]["lam"] == 0.0, delay
        assert main([*first, "--overwrite"]) == 0  # back to the old pair for the next delay
        old = tree_digest(sel), tree_digest(mat)
    assert "old" in seen  # the early interrupts at least hit the run


@pytest.mark.slow
def test_evaluate_keeps_results_and_card_entry_together(small_darkroom_batched, tmp_path):
    model, ev = tmp_path / "m", tmp_path / "m" / "eval"
    train = ["train", "--dataset", str(small_darkroom_batched.root), "--objective", "ad",
             "--preset", "tiny", "--max-steps", "2", "--batch-size", "4", "--out", str(model)]  # fmt: skip
    assert main(train) == 0
    first = [
        "evaluate",
        "--model",
        str(model),
        "--tasks",
        "38",
        "--episodes",
        "30",
        "--out",
        str(ev),
    ]
    assert main(first) == 0
    for delay in DELAYS:
        rc, err = _interrupt([*first, "--overwrite", "--seed", "7"], delay, tmp_path)
        assert "Traceback" not in err, err[-3000:]
        assert not list(model.glob(".*.replaced-*")), (delay, err)
        seed = json.loads((ev / "eval_results.json").read_text())["config"]["seed"]
        entries = json.loads((model / "evaluations.json").read_text())
        assert [e["seed"] for e in entries if e["out"] == str(ev.resolve())] == [seed], delay
        assert verify(ev)["problems"] == [], delay
        if seed == 7:  # the new one, whole: finished, or interrupted just after its switch
            assert rc == 0 or (rc == 130 and "after it completed the evaluation" in err), (
                delay,
                rc,
                err,
            )
        else:
            assert rc == 130 and "interrupted" in err, (delay, rc, err)
        if seed == 7:
            assert main([*first, "--overwrite"]) == 0
