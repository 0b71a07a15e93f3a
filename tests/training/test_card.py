"""The model card's instructions run as written: its Python snippets (transformers alone; a rollout
with lhf_hf) and its ``lhf evaluate`` command, taken from the card of a trained checkpoint."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from lhf_hf.envs import split_part
from lhf_hf.training.card import _final_loss, _rollout_tasks

REPO = Path(__file__).resolve().parents[2]


def _blocks(card: str, language: str) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```$", card, flags=re.DOTALL | re.MULTILINE)


def _run(args, cwd: Path, **kwargs) -> subprocess.CompletedProcess:
    """In a fresh process, outside the source tree, with the venv's console scripts on PATH."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    env["HF_MODULES_CACHE"] = str(cwd / "hf_modules")  # transformers' copy of the model code
    proc = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=600,
                          **kwargs)  # fmt: skip
    assert proc.returncode == 0, f"{args}\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    return proc


@pytest.mark.slow
def test_the_cards_python_snippets_run_as_written(tiny_model, tmp_path):
    card = (tiny_model / "README.md").read_text()
    snippets = _blocks(card, "python")
    assert len(snippets) == 2, snippets
    transformers_alone, with_lhf = snippets
    assert "trust_remote_code=True" in transformers_alone and "lhf_hf" not in transformers_alone
    assert f"{json.dumps(str(tiny_model.resolve()))}" in with_lhf  # the card of the local folder
    for i, code in enumerate(snippets):
        (tmp_path / f"snippet_{i}.py").write_text(code)
        _run([sys.executable, f"snippet_{i}.py"], tmp_path)
    # the first ran the checkpoint's own code: transformers copied it for the import
    assert list((tmp_path / "hf_modules").rglob("modeling_icrl.py"))


@pytest.mark.slow
def test_the_cards_evaluate_command_runs_as_written(tiny_model, tmp_path):
    from transformers import AutoConfig

    from lhf_hf.training.card import write_model_card

    model = tmp_path / "dicp"  # a copy (the evaluation adds itself to the card), with its card
    shutil.copytree(tiny_model, model)
    provenance = json.loads((model / "train_config.json").read_text())
    card = write_model_card(model, AutoConfig.from_pretrained(model), provenance).read_text()
    assert "Not evaluated yet" in card
    (command,) = [line for b in _blocks(card, "bash") for line in b.splitlines() if "lhf " in line]
    # its data held one test task (62): the card names the others, so the command runs as written
    unseen = [t for t in split_part("darkroom", "test", 0) if t != 62]
    assert command == (
        f"lhf evaluate --model {model.resolve()} --out dicp-eval --tasks {','.join(map(str, unseen))}"
    )
    (tmp_path / "cwd").mkdir()
    _run(command, tmp_path / "cwd", shell=True)
    results = json.loads((tmp_path / "cwd" / "dicp-eval" / "eval_results.json").read_text())
    assert results["config"]["episodes"] == 100 and results["task_label"] == "unseen tasks"
    assert "Not evaluated yet" not in (model / "README.md").read_text()


def test_the_card_rolls_out_on_the_test_tasks_the_model_did_not_train_on():
    test = split_part("darkroom", "test", 0)

    def tasks(trained):
        expr, note, flags = _rollout_tasks(SimpleNamespace(train_tasks=trained), "darkroom", 0)
        model = SimpleNamespace(config=SimpleNamespace(train_tasks=trained))
        return eval(expr, {"split_part": split_part, "model": model}), note, flags  # as the card

    assert tasks([0, 1]) == (test, "the test tasks of split 0, unseen in training", [])
    some, note, flags = tasks([test[0], 1])
    assert some == test[1:] and "but the 1 it trained on" in note
    assert flags == ["--tasks", ",".join(map(str, test[1:]))]
    assert tasks(test)[0] == test and tasks(test)[2] == ["--allow-seen"]  # reported as seen
    assert tasks(None)[0] == test and tasks(None)[2] == ["--allow-seen"]  # not recorded


def test_a_run_shorter_than_its_logging_interval_says_why_it_has_no_final_loss():
    logged = {"final_loss": 1.23456, "metrics": {"train_loss": 2.0}}
    assert _final_loss(logged) == "1.2346"
    short = {"final_loss": None, "metrics": {"train_loss": 1.5}, "train": {"logging_steps": 10}}
    assert _final_loss(short) == (
        "- (none logged: --logging-steps 10 is past the run's end; mean over the run 1.5000)"
    )
    assert _final_loss({"final_loss": None}) == "- (none logged)"
