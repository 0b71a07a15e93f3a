"""Split safety: a model records the tasks it trained on, and evaluation never calls them unseen."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from transformers import AutoConfig

from lhf_hf.cli.main import main
from lhf_hf.configs import CollectConfig, EvalConfig, TrainConfig
from lhf_hf.envs import get_spec, task_split
from lhf_hf.evaluation import evaluate
from lhf_hf.evaluation.seen import SeenTasksError, seen_label, seen_tasks
from lhf_hf.modeling import ICRLModel, icrl_config
from lhf_hf.training import train

TINY = dict(preset="tiny", batch_size=4, context_length=40, max_steps=2, save_steps=1)


class _Config:
    def __init__(self, train_tasks, split_seed):
        self.train_tasks, self.split_seed = train_tasks, split_seed


def test_seen_tasks_by_task_identity():
    dark, mw = get_spec("darkroom"), get_spec("metaworld-reach")
    # gridworld task ids name the same goal under every split seed
    assert seen_tasks(dark, _Config([3, 40, 60], 0), [60, 57, 3], split_seed=1) == [3, 60]
    assert seen_tasks(dark, _Config([3, 40], 0), [5, 6], split_seed=0) == []
    # Meta-World's goals are drawn from the split seed: task 10 of seed 1 is another goal
    assert seen_tasks(mw, _Config([10, 11], 0), [10, 50], split_seed=0) == [10]
    assert seen_tasks(mw, _Config([10, 11], 0), [10, 50], split_seed=1) == []
    assert seen_tasks(dark, _Config(None, None), [5], split_seed=0) is None
    assert seen_label([], 8) == "unseen tasks"
    assert seen_label([], 8, "test") == "unseen tasks"
    assert seen_label([], 8, "validation") == "validation tasks"
    assert seen_label([12], 8, "validation") == "seen tasks (1 of 8)"  # seen wins
    assert seen_label([62], 8) == "seen tasks (1 of 8)"
    assert seen_label([1, 2], 2) == "seen tasks"
    assert seen_label(None, 8).startswith("seen tasks")


def test_curve_titles():
    from lhf_hf.evaluation.evaluate import _curve_title

    assert _curve_title("darkroom", 8, "test", "unseen tasks") == (
        "darkroom: 8 test tasks, unseen tasks, in context"
    )
    assert _curve_title("darkroom", 8, "validation", "validation tasks") == (
        "darkroom: 8 validation tasks, in context"
    )
    assert _curve_title("darkroom", 8, "test", "seen tasks (1 of 8)") == (
        "darkroom: 8 test tasks, seen tasks (1 of 8), in context"
    )


def test_collect_defaults_to_the_train_split():
    train_tasks, test_tasks = task_split("darkroom", 2)
    cfg = CollectConfig("darkroom", split_seed=2)
    assert cfg.tasks == sorted(train_tasks) and not set(cfg.tasks) & set(test_tasks)
    assert len(CollectConfig("darkroom", tasks="all").tasks) == 81


@pytest.fixture(scope="module")
def trained(small_darkroom, tmp_path_factory):
    """A tiny AD on the small dataset: tasks 3, 40 (train tasks of split 0) and 62 (a test task)."""
    out = tmp_path_factory.mktemp("seen") / "m"
    train(TrainConfig(dataset=str(small_darkroom.root), objective="ad", out=str(out), **TINY))
    return out


def test_the_model_and_every_checkpoint_record_the_training_tasks(trained):
    for folder in [trained, *sorted(trained.glob("checkpoint-*"))]:
        config = AutoConfig.from_pretrained(folder)
        assert config.train_tasks == [3, 40, 62] and config.split_seed == 0, folder
    prov = json.loads((trained / "train_config.json").read_text())
    assert prov["dataset"]["tasks"] == [3, 40, 62]
    assert prov["dataset"]["split_coverage"]["test_tasks_trained_on"] == [62]


def test_evaluate_refuses_trained_on_tasks_unless_allowed(trained, tmp_path):
    # the default test tasks of split 0 hold 62, which the model trained on
    with pytest.raises(SeenTasksError, match=r"1 of the 8 evaluation tasks .*\(62\)"):
        evaluate(EvalConfig(model=str(trained), out=str(tmp_path / "e"), episodes=1), False)
    assert not (tmp_path / "e").exists()  # nothing written
    # also from a checkpoint folder (its config carries the split; no train_config.json there)
    ckpt = sorted(trained.glob("checkpoint-*"))[-1]
    with pytest.raises(SeenTasksError, match="62"):
        evaluate(EvalConfig(model=str(ckpt), out=str(tmp_path / "c"), episodes=1), False)
    # asked explicitly: evaluated and labelled everywhere
    res = evaluate(
        EvalConfig(model=str(trained), out=str(tmp_path / "e"), episodes=1, allow_seen=True), False
    )
    assert res["seen_tasks"] == [62] and res["task_label"] == "seen tasks (1 of 8)"
    assert res["split_seed"] == 0 and res["tasks"] == task_split("darkroom", 0)[1]
    card = (trained / "README.md").read_text()
    assert "| seen tasks (1 of 8) |" in card and "test-split-0-seen" in card


def test_another_split_seed_cannot_smuggle_training_goals(small_darkroom, tmp_path):
    """A split-0 model evaluated with --split-seed 1: its test goals include train goals of split 0."""
    sub = tmp_path / "d"
    assert main(["collect", "darkroom", "--out", str(sub), "--tasks", "3,60", "--histories", "4",
                 "--steps", "200", "--collector", "batched", "--no-progress"]) == 0  # fmt: skip
    model = tmp_path / "m"
    train(TrainConfig(dataset=str(sub), objective="ad", out=str(model), **TINY))
    # its own split: 3 and 60 are train tasks of split 0, all 8 test tasks unseen
    res = evaluate(EvalConfig(model=str(model), out=str(tmp_path / "e0"), episodes=1), False)
    assert res["seen_tasks"] == [] and res["task_label"] == "unseen tasks"
    with pytest.raises(SeenTasksError, match=r"\(60\).*own split \(split seed 0"):
        evaluate(
            EvalConfig(model=str(model), out=str(tmp_path / "e1"), episodes=1, split_seed=1), False
        )


def test_a_model_without_a_record_is_refused_unless_allowed(tmp_path, capsys):
    model = ICRLModel(icrl_config("tiny", objective="ad", env_id="darkroom", context_length=40))
    model.save_pretrained(tmp_path / "m")
    ev = ["evaluate", "--model", str(tmp_path / "m"), "--episodes", "1", "--out"]
    assert main([*ev, str(tmp_path / "e")]) == 1
    err = capsys.readouterr().err
    assert "does not record the tasks it was trained on" in err and "Traceback" not in err
    assert main([*ev, str(tmp_path / "e"), "--allow-seen"]) == 0
    res = json.loads((tmp_path / "e" / "eval_results.json").read_text())
    assert res["seen_tasks"] is None and res["task_label"].startswith("seen tasks")


def test_compare_labels_seen_rows(trained, tmp_path):
    from lhf_hf.evaluation.compare import backbone_of

    res = evaluate(
        EvalConfig(model=str(trained), out=str(tmp_path / "e"), episodes=1, allow_seen=True), False
    )
    assert backbone_of(res) == "AD [seen tasks]"
    shutil.rmtree(tmp_path / "e")
    assert backbone_of({"objective": "ad", "config": {}, "task_label": "unseen tasks"}) == "AD"


def test_train_says_which_split_its_data_covers(small_darkroom, tmp_path, capsys):
    out = Path(tmp_path / "m")
    train(TrainConfig(dataset=str(small_darkroom.root), objective="ad", out=str(out), **TINY))
    err = capsys.readouterr().err
    assert "2 of the 73 train tasks of darkroom split seed 0 and 1 of its 8 test tasks" in err


def test_concurrent_evaluations_keep_every_card_entry(trained):
    """Each evaluation appends to the model's evaluations under a lock: none is lost."""
    from concurrent.futures import ThreadPoolExecutor

    from lhf_hf.evaluation.evaluate import _add_to_model_card

    before = (
        json.loads((trained / "evaluations.json").read_text())
        if (trained / "evaluations.json").exists()
        else []
    )

    def one(i):
        _add_to_model_card(trained, {
            "config": {"out": f"/tmp/concurrent-{i}", "tasks": "test", "episodes": 1, "plan": False,
                       "seed": i, "model": str(trained)},
            "env_id": "darkroom", "split_seed": 0, "tasks": [38], "task_label": "unseen tasks",
            "rollouts": 1, "context": "window", "mean_return": 0.0, "final_return": 0.0,
            "success_rate": None,
        })  # fmt: skip

    with ThreadPoolExecutor(8) as pool:
        list(pool.map(one, range(8)))
    after = json.loads((trained / "evaluations.json").read_text())
    assert len(after) == len(before) + 8


def test_a_record_edited_after_training_is_not_trusted(trained, tmp_path):
    """Emptying `train_tasks` in config.json would make every task "unseen": the model folder's
    manifest says config.json changed, so evaluate refuses it; compare refuses an edited result."""
    from lhf_hf.evaluation.compare import compare

    model = tmp_path / "m"
    shutil.copytree(trained, model)
    ev = evaluate(
        EvalConfig(model=str(model), out=str(tmp_path / "e"), episodes=1, tasks="38"), False
    )
    assert ev["task_label"] == "unseen tasks"
    results = tmp_path / "e" / "eval_results.json"
    results.write_text(results.read_text().replace('"mean_return": ', '"mean_return": 1', 1))
    with pytest.raises(ValueError, match="changed since `lhf evaluate` wrote it"):
        compare([str(tmp_path / "e")], [str(tmp_path / "e")])
    conf = model / "config.json"
    conf.write_text(json.dumps({**json.loads(conf.read_text()), "train_tasks": []}))
    with pytest.raises(ValueError, match=r"config.json changed since `lhf train` wrote it"):
        evaluate(EvalConfig(model=str(model), out=str(tmp_path / "e2"), tasks="train",
                            episodes=1), False)  # fmt: skip


@pytest.mark.parametrize("content", ["[1, 2]", '[{"out": "x"}]', '{"a": 1}'])
def test_a_damaged_evaluations_list_is_refused_before_the_rollouts(trained, tmp_path, content):
    from lhf_hf.training.artifact import CheckpointArtifact

    model = tmp_path / "m"
    shutil.copytree(trained, model)
    (model / "evaluations.json").write_text(content)
    with pytest.raises(ValueError, match="evaluations.json .*the file is damaged"):
        evaluate(
            EvalConfig(model=str(model), out=str(tmp_path / "e"), episodes=1, tasks="38"), False
        )
    assert not (tmp_path / "e").exists()
    assert any("evaluations.json" in p for p in CheckpointArtifact.verify(model))


def test_validation_tasks_are_evaluated_by_name(trained, tmp_path, capsys):
    """`--tasks validation`: split 0's held-out train tasks, none of which this model trained on,
    labelled "validation tasks" (not the unseen test tasks results are reported on) in the
    command's line, the results, the card and compare's row; `--tasks train` holds 3 and 40,
    which it did."""
    model = tmp_path / "m"
    shutil.copytree(trained, model)
    out = tmp_path / "v"
    argv = ["evaluate", "--model", str(model), "--out", str(out), "--episodes", "1"]
    assert main([*argv, "--tasks", "validation", "--no-progress"]) == 0
    assert capsys.readouterr().out.startswith("darkroom, validation tasks (8 tasks, 1 episode): ")
    res = json.loads((out / "eval_results.json").read_text())
    assert sorted(res["tasks"]) == [2, 35, 42, 44, 54, 55, 77, 80]
    assert res["task_label"] == "validation tasks" and res["seen_tasks"] == []
    card = (model / "README.md").read_text()
    # (the model's card also lists the evaluations earlier tests made of it)
    rows = [line for line in card.splitlines() if line.startswith("| darkroom | 8 validation |")]
    assert len(rows) == 1 and rows[0].startswith(
        "| darkroom | 8 validation | validation tasks | 0 |"
    )
    assert "validation-split-0-seen" not in card and "config: validation-split-0\n" in card
    from lhf_hf.evaluation.compare import backbone_of

    assert backbone_of(res) == "AD"  # not seen
    with pytest.raises(SeenTasksError, match=r"\(3, 40\).*Evaluate on --tasks validation"):
        evaluate(EvalConfig(model=str(trained), out=str(tmp_path / "t"), episodes=1,
                            tasks="train"), False)  # fmt: skip
    # a task index beyond the env's tasks is an expected failure (one line), not an IndexError bug
    from lhf_hf.errors import OutOfRangeError, UserError

    with pytest.raises(OutOfRangeError, match="task index 999 out of range") as info:
        evaluate(EvalConfig(model=str(trained), out=str(tmp_path / "r"), episodes=1,
                            tasks="999"), False)  # fmt: skip
    assert isinstance(info.value, UserError)


def test_the_seen_hint_names_the_fix_for_validation_tasks(tmp_path):
    """A model trained on all train tasks covers the validation tasks: the fix is fit data."""
    from lhf_hf.evaluation.seen import check_unseen

    dark = get_spec("darkroom")
    validation = [2, 35, 42, 44, 54, 55, 77, 80]
    model = _Config(task_split("darkroom", 0)[0], 0)  # trained on --tasks train
    with pytest.raises(SeenTasksError, match="train on data collected with --tasks fit"):
        check_unseen(dark, model, validation, 0, False, "m")


def test_tuning_tools_measure_on_validation_goals_and_test_goals_only_to_report():
    from lhf_hf.errors import UserError
    from lhf_hf.evaluation.seen import tuning_tasks

    # split 0 of Darkroom, by hand (tests/envs/test_registry.py): 8 validation goals
    validation = sorted(tuning_tasks("darkroom", "validation", 0, False))
    assert validation == [2, 35, 42, 44, 54, 55, 77, 80]
    with pytest.raises(UserError, match="test goals are for reporting only.*--report-on-test"):
        tuning_tasks("darkroom", "test", 0, False)
    assert tuning_tasks("darkroom", "test", 0, True) == task_split("darkroom", 0)[1]
    with pytest.raises(UserError, match="one of \\('validation', 'test'\\)"):
        tuning_tasks("darkroom", "train", 0, True)
