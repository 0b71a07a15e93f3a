"""Trainer arguments: ``--report-to`` and ``--training-arg KEY=VALUE`` are checked before training,
read as their fields' types, reach the Trainer and are recorded with the checkpoint."""

from __future__ import annotations

import json

import pytest
import torch
from transformers import TrainerCallback
from transformers.integrations import integration_utils

from lhf_hf.cli.main import build_parser, main
from lhf_hf.configs import TrainConfig
from lhf_hf.configs.train import TRAINING_ARGS_FIXED, TRAINING_ARGS_FROM_FLAGS
from lhf_hf.errors import MissingExtraError, UnknownNameError, UserError
from lhf_hf.training import arguments, build_trainer, train
from lhf_hf.training.arguments import parse_training_args, training_arg_types

BASE = dict(objective="ad", preset="tiny", context_length=40, batch_size=4)


def test_training_args_are_read_as_their_fields_types():
    got = parse_training_args(
        {
            "adam_epsilon": "1e-6",  # float
            "dataloader_num_workers": "2",  # int
            "logging_first_step": "true",  # bool
            "lr_scheduler_type": "linear",  # SchedulerType | str
            "lr_scheduler_kwargs": '{"num_cycles": 2}',  # dict | str | None
            "torch_empty_cache_steps": "none",  # int | None
            "label_names": "action_labels,reward_labels",  # list[str] | None
            "run_name": "as given",  # str
            "data_seed": 7,  # from Python: already typed
        }
    )
    assert got == {
        "adam_epsilon": 1e-6,
        "dataloader_num_workers": 2,
        "logging_first_step": True,
        "lr_scheduler_type": "linear",
        "lr_scheduler_kwargs": {"num_cycles": 2},
        "torch_empty_cache_steps": None,
        "label_names": ["action_labels", "reward_labels"],
        "run_name": "as given",
        "data_seed": 7,
    }


@pytest.mark.parametrize(
    "given, error, match",
    [
        ({"lr_schedular_type": "linear"}, UnknownNameError, "did you mean 'lr_scheduler_type'"),
        ({"adam_epsilon": "tiny"}, UserError, r"\['adam_epsilon'\] must be a number, got 'tiny'"),
        ({"logging_first_step": "maybe"}, UserError, "must be true or false"),
        ({"dataloader_num_workers": "1.5"}, UserError, "must be an integer"),
        ({"lr_scheduler_type": "cosin"}, UserError, "one of linear, cosine.*did you mean 'cosine'"),
        ({"lr_scheduler_kwargs": "{num_cycles: 2}"}, UserError, "not valid JSON"),
        ({"data_seed": 1.5}, UserError, "must be an integer or none, got 1.5"),
        ({"data_seed": object()}, UserError, "a number, text, true/false, a list or a mapping"),
    ],
)
def test_bad_training_args_are_named(given, error, match):
    with pytest.raises(error, match=match):
        parse_training_args(given)


@pytest.mark.parametrize("key", [*TRAINING_ARGS_FROM_FLAGS, *TRAINING_ARGS_FIXED])
def test_the_arguments_lhf_sets_are_refused_with_the_flag_or_the_reason(key):
    assert key in training_arg_types()  # a field TrainingArguments has (a rename shows here)
    with pytest.raises(UserError, match=f"training_args: '{key}' is (set by lhf's own flag: use "
                                        f"--|fixed by lhf: )"):  # fmt: skip
        TrainConfig(dataset="d", out="o", training_args={key: "1"}, **BASE)


def test_report_to_names_are_checked(monkeypatch):
    for bad in ("", "none,tensorboard", "Tensor Board"):
        with pytest.raises(UserError, match="TrainConfig.report_to"):
            TrainConfig(dataset="d", out="o", report_to=bad, **BASE)
    assert TrainConfig(dataset="d", out="o", report_to="wandb, trackio", **BASE).reporters == [
        "wandb", "trackio"]  # fmt: skip
    cfg = TrainConfig(dataset="d", out="o", report_to="tensorbord", **BASE)
    with pytest.raises(UnknownNameError, match="did you mean 'tensorboard'"):
        arguments.check_reporters(cfg)
    monkeypatch.setattr(arguments, "installed_reporters", lambda: set())
    for name, pip in (("tensorboard", "tensorboard"), ("comet_ml", "comet-ml")):
        cfg = TrainConfig(dataset="d", out="o", report_to=name, **BASE)
        with pytest.raises(MissingExtraError, match=f"not installed here \\(pip install {pip}\\)"):
            arguments.check_reporters(cfg)
    arguments.check_reporters(TrainConfig(dataset="d", out="o", report_to="all", **BASE))


def test_a_reporter_not_installed_fails_before_anything_is_written(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(arguments, "installed_reporters", lambda: set())
    out = tmp_path / "m"
    argv = ["train", "--dataset", str(tmp_path / "no-data"), "--objective", "ad", "--out", str(out),
            "--report-to", "tensorboard"]  # fmt: skip
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "lhf train: error: --report-to tensorboard: the tensorboard integration is not " in err
    assert not out.exists()  # checked before the folder is claimed (and the dataset read)


def test_the_cli_gives_the_fields(tmp_path, capsys):
    parser = build_parser()
    argv = ["train", "--dataset", "d", "--objective", "ad", "--out", "o"]
    args = parser.parse_args([*argv, "--training-arg", "adam_epsilon=1e-6", "--report-to", "all",
                              "--training-arg", "run_name=a=b", "--training-arg", " data_seed =3"])  # fmt: skip
    fields = {n: getattr(args, n) for n in args.fields if hasattr(args, n)}
    assert fields["training_args"] == {"adam_epsilon": "1e-6", "run_name": "a=b", "data_seed": "3"}
    assert fields["report_to"] == "all"
    with pytest.raises(SystemExit):
        parser.parse_args([*argv, "--training-arg", "adam_epsilon"])
    assert "expected KEY=VALUE, got 'adam_epsilon'" in capsys.readouterr().err
    assert main([*argv, "--training-arg", "learning_rate=0.1"]) == 1
    assert "'learning_rate' is set by lhf's own flag: use --lr" in capsys.readouterr().err


def test_other_arguments_and_the_flags_reach_the_trainer(small_darkroom, tmp_path):
    cfg = TrainConfig(
        dataset=str(small_darkroom.root), out=str(tmp_path / "m"), logging_steps=3,
        weight_decay=0.1, training_args={"adam_epsilon": "1e-6", "lr_scheduler_type": "linear"},
        **BASE,
    )  # fmt: skip
    trainer, prov = build_trainer(cfg)
    a = trainer.args
    assert (a.logging_steps, a.weight_decay, a.adam_epsilon) == (3, 0.1, 1e-6)
    assert a.lr_scheduler_type == "linear" and a.report_to == []
    assert prov["train"]["training_args"] == {"adam_epsilon": 1e-6, "lr_scheduler_type": "linear"}
    assert trainer.lhf_identity["train"]["training_args"] == prov["train"]["training_args"]
    refused = TrainConfig(**{**cfg.to_dict(), "training_args": {"eval_strategy": "steps"}})
    with pytest.raises(
        UserError, match="TrainConfig.training_args .eval_strategy=.steps..: refused by Trainer: You have set"
    ):
        build_trainer(refused)


class _Recorder(TrainerCallback):
    """A stand-in reporting integration: what Trainer reports to it."""

    logs: list[dict] = []

    def on_log(self, args, state, control, logs=None, **kwargs):
        if state.is_world_process_zero:
            _Recorder.logs.append(dict(logs or {}))


@pytest.mark.slow
def test_a_run_reports_and_records_its_arguments(small_darkroom, tmp_path, monkeypatch):
    """An installed integration (tensorboard is not in the lock: a recorder stands in for it)
    gets Trainer's logs; the arguments are in train_config.json, training_args.json and the card;
    resuming with other arguments is refused."""
    monkeypatch.setitem(integration_utils.INTEGRATION_TO_CALLBACK, "tensorboard", _Recorder)
    monkeypatch.setattr(arguments, "installed_reporters", lambda: {"tensorboard"})
    _Recorder.logs = []
    cfg = TrainConfig(
        dataset=str(small_darkroom.root), out=str(tmp_path / "m"), max_steps=4, save_steps=2,
        logging_steps=2, report_to="tensorboard", training_args={"adam_epsilon": "1e-6"}, **BASE,
    )  # fmt: skip
    out = train(cfg)
    assert any("loss" in r for r in _Recorder.logs), _Recorder.logs
    prov = json.loads((out / "train_config.json").read_text())
    assert prov["train"]["report_to"] == "tensorboard"
    assert prov["train"]["training_args"] == {"adam_epsilon": 1e-6}
    args = json.loads((out / "training_args.json").read_text())
    assert args["adam_epsilon"] == 1e-6 and args["report_to"] == ["tensorboard"]
    assert "TrainingArguments also set: `adam_epsilon=1e-06`" in (out / "README.md").read_text()
    (out / "config.json").unlink()  # unfinished: resumable from checkpoint-2
    again = TrainConfig(
        **{**cfg.to_dict(), "resume": True, "training_args": {"adam_epsilon": 1e-5}}
    )
    with pytest.raises(UserError, match=r"training_args: \{'adam_epsilon': 1e-06\} -> "):
        train(again)


@pytest.mark.parametrize(
    "given, match",
    [
        ({"dataloader_num_workers": "-1"}, "dataloader_num_workers must be 0 or more"),
        ({"fp16": "true"}, "fp16 needs a CUDA GPU; on a CPU use bf16=true"),
    ],
)
def test_what_trainingarguments_accepts_but_a_run_cannot_use_is_refused_first(
    small_darkroom, tmp_path, given, match
):
    if "fp16" in given and torch.cuda.is_available():
        pytest.skip("fp16 runs on a GPU")
    out = tmp_path / "m"
    cfg = TrainConfig(dataset=str(small_darkroom.root), out=str(out), training_args=given, **BASE)
    with pytest.raises(UserError, match=f"TrainConfig.training_args .*: refused by lhf: {match}"):
        train(cfg)
    assert not out.exists()
