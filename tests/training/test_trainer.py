"""``train``: the three objectives learn, provenance and cards, selections, resume, bad input, CLI."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file
from transformers import AutoModel

from lhf_hf.cli.main import main
from lhf_hf.configs import FilterConfig, TrainConfig
from lhf_hf.envs import get_spec
from lhf_hf.filtering.select import filter_histories
from lhf_hf.modeling import AUTO_MAP, MODEL_CODE_FILES, ICRLModel, attention_kernel, icrl_config
from lhf_hf.modeling.remote_code import model_code
from lhf_hf.training import build_trainer, check_model_env, model_config_for, train
from lhf_hf.training.trainer import last_checkpoint
from lhf_hf.utils.launcher import accelerate_config

REPO = Path(__file__).resolve().parents[2]
TINY = dict(
    preset="tiny", batch_size=8, context_length=40, lr=3e-3, logging_steps=10, save_steps=1000
)


def losses(out: Path) -> list[float]:
    return [r["loss"] for r in json.loads((out / "training_log.json").read_text()) if "loss" in r]


@pytest.mark.slow
@pytest.mark.parametrize("objective", ["ad", "dpt", "dicp"])
def test_each_objective_learns_and_saves_a_loadable_checkpoint(
    learned_darkroom, tmp_path, objective
):
    out = train(
        TrainConfig(
            dataset=str(learned_darkroom.root),
            objective=objective,
            out=str(tmp_path / "m"),
            max_steps=80,
            **TINY,
        )
    )
    loss = losses(out)
    assert len(loss) == 8 and np.mean(loss[-2:]) < 0.9 * np.mean(loss[:2]), loss
    model = AutoModel.from_pretrained(out)
    assert isinstance(model, ICRLModel) and model.config.objective == objective
    assert model.config.env_id == "darkroom" and model.config.return_scale == 20.0
    prov = json.loads((out / "train_config.json").read_text())
    assert prov["dataset"]["fingerprint"] == learned_darkroom.fingerprint
    assert prov["train"]["seed"] == 0 and prov["global_step"] == 80 and prov["selection"] is None
    assert {"torch", "transformers", "accelerate", "datasets"} <= set(prov["versions"])
    card = (out / "README.md").read_text()
    assert card.startswith("---\n") and "in-context-rl" in card and objective.upper() in card
    assert (out / "training_loss.png").stat().st_size > 0


@pytest.mark.slow
def test_band_attention_trains_on_sequences_and_evaluates_with_the_stream(
    learned_darkroom, tmp_path
):
    """attention="band": sequences of 4 x K transitions (the default), the model records its
    attention, the identity its sequence length, and evaluation runs the streaming cache."""
    from lhf_hf.configs import EvalConfig
    from lhf_hf.evaluation import evaluate

    out = train(
        TrainConfig(
            dataset=str(learned_darkroom.root),
            objective="dicp",
            out=str(tmp_path / "m"),
            max_steps=40,
            attention="band",
            **TINY,
        )  # fmt: skip
    )
    loss = losses(out)
    assert len(loss) == 4 and loss[-1] < loss[0], loss
    model = AutoModel.from_pretrained(out)
    assert model.config.attention == "band" and model.config.context_length == 40
    result = evaluate(EvalConfig(model=str(out), out=str(tmp_path / "e"), episodes=3), False)
    assert result["context"] == "cache" and result["config"]["context"] == "auto"
    # the resolved sequence length is recorded, so resuming with it written out is the same run
    prov = json.loads((out / "train_config.json").read_text())
    assert prov["sequence_length"] == 160
    # so is the reward weighting (unset: the reference's 'data'); the flag is kept as given
    assert prov["reward_weighting"] == "data" and prov["train"]["reward_weighting"] is None
    # and the attention code that ran (auto: the kernel where it builds; attention_kernel.py)
    kernel = "kernel" if attention_kernel.available() is None else "torch"
    assert prov["attention_kernel"] == kernel and prov["train"]["attention_kernel"] == "auto"
    card = (out / "README.md").read_text()  # the card says how it was trained and evaluated
    assert "sequences of 160 transitions, band attention over the last 40" in card
    assert "reward loss weighting 'data'" in card
    assert "| no | cache |" in card and "context cache" in card
    explicit = TrainConfig(dataset=str(learned_darkroom.root), objective="dicp", out=str(out),
                           max_steps=40, attention="band", sequence_length=160, resume=True,
                           **TINY)  # fmt: skip
    train(explicit)  # nothing left to do, but the identity check passes
    with pytest.raises(ValueError, match="sequence_length: 160 -> 120"):
        train(dataclasses.replace(explicit, sequence_length=120))
    # the unset weighting and 'data' written out are one run; 'actions' is another
    train(dataclasses.replace(explicit, reward_weighting="data"))
    with pytest.raises(ValueError, match="reward_weighting: 'data' -> 'actions'"):
        train(dataclasses.replace(explicit, reward_weighting="actions"))


def test_selection_counts_weight_the_windows(small_darkroom, tmp_path):
    sel = filter_histories(small_darkroom, FilterConfig())
    sel.save(tmp_path / "sel")
    cfg = TrainConfig(
        dataset=str(small_darkroom.root),
        selection=str(tmp_path / "sel"),
        objective="ad",
        out=str(tmp_path / "m"),
        max_steps=5,
        **TINY,
    )
    trainer, prov = build_trainer(cfg)
    counts = np.array([sel.counts()[h] for h in trainer.train_dataset.arrays.history_index])
    np.testing.assert_array_equal(trainer.train_dataset.counts, counts)
    assert prov["windows"] == len(trainer.train_dataset) == counts.sum() * (200 - 40 + 1)
    assert prov["selection"]["selected_unique"] == int((counts > 0).sum())


def test_selection_of_another_dataset_is_rejected(small_darkroom, small_darkroom_batched, tmp_path):
    filter_histories(small_darkroom_batched, FilterConfig()).save(tmp_path / "sel")
    cfg = TrainConfig(
        dataset=str(small_darkroom.root),
        selection=str(tmp_path / "sel"),
        objective="ad",
        out=str(tmp_path / "m"),
        **TINY,
    )
    with pytest.raises(ValueError, match="fingerprint"):
        build_trainer(cfg)


def test_bad_inputs_fail_before_training(small_darkroom, tmp_path):
    base = dict(dataset=str(small_darkroom.root), out=str(tmp_path / "m"))
    with pytest.raises(ValueError, match="longer than the shortest history"):
        build_trainer(TrainConfig(objective="ad", **{**base, **TINY, "context_length": 201}))
    with pytest.raises(ValueError, match="DPT needs the oracle"):
        model_config_for(
            get_spec("metaworld-reach"), TrainConfig(objective="dpt", **base), has_optimal=False
        )
    with pytest.raises(ValueError, match="DPT needs the oracle"):
        model_config_for(
            get_spec("darkroom"), TrainConfig(objective="dpt", **base), has_optimal=False
        )
    continuous = icrl_config("tiny", state_dim=2, action_dim=5, discrete_actions=False)
    with pytest.raises(ValueError, match="continuous action head"):
        build_trainer(TrainConfig(objective="ad", **base), model_config=continuous)
    with pytest.raises(ValueError, match="discrete action head"):
        check_model_env(
            icrl_config("tiny", state_dim=39, action_dim=4), get_spec("metaworld-reach")
        )
    with pytest.raises(ValueError, match="objective"):
        TrainConfig(objective="bc", **base)
    with pytest.raises(ValueError, match="sequence_length is for attention='band' only"):
        TrainConfig(objective="ad", sequence_length=200, **base)
    with pytest.raises(ValueError, match="sequence_length must be >= context_length=80"):
        TrainConfig(objective="ad", attention="band", context_length=80, sequence_length=40, **base)
    with pytest.raises(ValueError, match="label_positions must be 'all' with attention='band'"):
        TrainConfig(objective="ad", attention="band", label_positions="query", **base)
    # the env's context (darkroom: 80) is the bound when --context-length is not given
    with pytest.raises(ValueError, match="sequence_length must be >= the context length 80"):
        build_trainer(TrainConfig(objective="ad", attention="band", sequence_length=40, **base))
    with pytest.raises(ValueError, match=r"sequences of 240 transitions \(the default: 4 x the"):
        build_trainer(TrainConfig(objective="ad", attention="band", context_length=60, **base))
    with pytest.raises(ValueError, match="state_encoding='cells' needs integer"):
        model_config_for(
            get_spec("metaworld-reach"),
            TrainConfig(objective="ad", state_encoding="cells", **base),
            has_optimal=False,
        )
    with pytest.raises(ValueError, match="metaworld-reach has real-valued rewards or actions"):
        model_config_for(
            get_spec("metaworld-reach"),
            TrainConfig(objective="dicp", reward_weighting="actions", **base),
            has_optimal=False,
        )
    with pytest.raises(ValueError, match="'actions' weighs DICP's .* ad has no reward head"):
        model_config_for(
            get_spec("darkroom"),
            TrainConfig(objective="ad", reward_weighting="actions", **base),
            has_optimal=False,
        )
    with pytest.raises(FileNotFoundError, match="no complete checkpoint"):
        train(TrainConfig(objective="ad", resume=True, **base))


@pytest.mark.parametrize(
    "env_id, objective, given, resolved",
    [
        ("darkroom", "dicp", None, "data"),  # the reference's plain loss
        ("darkroom", "dicp", "actions", "actions"),  # ours, asked for
        ("darkroom", "dicp", "data", "data"),
        ("darkroom", "ad", None, "data"),  # no reward head
        ("metaworld-reach", "dicp", None, "data"),  # a regression head
    ],
)
def test_reward_weighting_default_resolves_per_env_and_objective(
    tmp_path, env_id, objective, given, resolved
):
    cfg = TrainConfig(dataset="d", out=str(tmp_path), objective=objective, reward_weighting=given)
    assert model_config_for(get_spec(env_id), cfg, has_optimal=True).reward_weighting == resolved


def test_existing_output_needs_resume_or_overwrite(small_darkroom, tmp_path):
    cfg = dict(
        dataset=str(small_darkroom.root),
        objective="ad",
        out=str(tmp_path / "m"),
        max_steps=3,
        **TINY,
    )
    train(TrainConfig(**cfg))
    with pytest.raises(FileExistsError, match="--resume"):
        train(TrainConfig(**cfg))
    train(TrainConfig(**cfg, overwrite=True))
    assert (tmp_path / "m" / "model.safetensors").exists()


def test_an_interrupt_before_the_first_checkpoint_leaves_nothing_to_resume(
    small_darkroom, tmp_path, monkeypatch, capsys
):
    """Ctrl-C before the first save: the folder the run created held only its in-progress
    marker, so it is removed, and the message says so and to run the command again (a --resume
    would have nothing to continue, and says that too)."""
    from lhf_hf.training.trainer import WindowTrainer
    from lhf_hf.utils import outputs

    def pressed(self, *args, **kwargs):
        raise KeyboardInterrupt

    # this command's, not those of the fixtures' commands in this process
    monkeypatch.setattr(outputs, "COMPLETED", [])
    monkeypatch.setattr(outputs, "DISCARDED", [])
    monkeypatch.setattr(WindowTrainer, "train", pressed)
    out = tmp_path / "m"
    args = ["train", "--dataset", str(small_darkroom.root), "--objective", "ad", "--preset",
            "tiny", "--max-steps", "4", "--batch-size", "4", "--out", str(out)]  # fmt: skip
    capsys.readouterr()
    assert main(args) == 130
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"lhf train: interrupted (before the model held anything to resume: {out.resolve()} is "
        "removed; run the command again)"
    )
    assert not out.exists() and not list(tmp_path.glob(".*"))
    monkeypatch.setattr(outputs, "DISCARDED", [])
    assert main([*args, "--resume"]) == 1
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"lhf train: error: --resume: no complete checkpoint-* folder in {out} to resume from: "
        "train without --resume"
    )
    assert not out.exists()


def test_resume_continues_identically(small_darkroom, learned_darkroom, tmp_path, capsys):
    cfg = dict(
        dataset=str(small_darkroom.root),
        objective="dicp",
        max_steps=12,
        **{**TINY, "save_steps": 6},
    )
    full = train(TrainConfig(out=str(tmp_path / "full"), **cfg))
    # an interrupted run: only the first checkpoint exists
    part = tmp_path / "part"
    part.mkdir()
    shutil.copytree(full / "checkpoint-6", part / "checkpoint-6")
    # ... and a save of checkpoint-12 cut short (weights truncated, no trainer state): passed over
    cut = part / "checkpoint-12"
    shutil.copytree(full / "checkpoint-12", cut)
    (cut / "trainer_state.json").unlink()
    (cut / "model.safetensors").write_bytes((cut / "model.safetensors").read_bytes()[:100])
    assert last_checkpoint(part) == str(part / "checkpoint-6")
    capsys.readouterr()
    resumed = train(TrainConfig(out=str(part), resume=True, **cfg))
    err = capsys.readouterr().err
    assert f"{cut} is incomplete" in err
    assert f"resuming from {part / 'checkpoint-6'} (step 6 of 12)" in err
    a, b = load_file(full / "model.safetensors"), load_file(resumed / "model.safetensors")
    for k in a:
        torch.testing.assert_close(b[k], a[k], rtol=0, atol=0, msg=k)
    assert json.loads((resumed / "train_config.json").read_text())["resumed_from"].endswith(
        "checkpoint-6"
    )
    # resuming with other settings or data is refused, naming what differs
    for changed, message in [
        ({"lr": 0.5}, r"lr: 0.003 -> 0.5"),
        ({"seed": 1}, r"seed: 0 -> 1"),
        ({"max_steps": 13}, r"max_steps: 12 -> 13"),
        ({"dataset": str(learned_darkroom.root)}, r"dataset: [0-9a-f]{16} -> [0-9a-f]{16}"),
        # the torch path draws other dropout masks than the kernel's (attention_kernel.py)
        *(
            [({"attention_kernel": "torch"}, r"attention_kernel: 'kernel' -> 'torch'")]
            if attention_kernel.available() is None
            else []
        ),
    ]:
        with pytest.raises(ValueError, match=f"different setup \\(.*{message}"):
            train(TrainConfig(out=str(part), resume=True, **{**cfg, **changed}))
    # Trainer's pickled TrainingArguments never stay: JSON beside the weights instead (the
    # checkpoints' optimizer/scheduler/RNG states are torch files Trainer loads weights_only)
    for out in (full, resumed):
        assert not list(out.rglob("training_args.bin")), out
        for folder in (out, out / "checkpoint-12"):
            args = json.loads((folder / "training_args.json").read_text())
            assert args["max_steps"] == 12 and args["seed"] == 0 and args["save_steps"] == 6


@pytest.mark.skipif(attention_kernel.available() is not None, reason="no attention kernel here")
def test_one_seed_is_one_run_with_the_attention_kernel(small_darkroom, tmp_path):
    """The kernel's dropout masks come from torch's generator, seeded by TrainConfig.seed: the same
    seed trains the same weights, another seed others (lightweight preset: attention dropout 0.1)."""
    cfg = dict(dataset=str(small_darkroom.root), objective="ad", max_steps=3,
               **{**TINY, "preset": "lightweight"}, attention_kernel="kernel")  # fmt: skip
    a = train(TrainConfig(out=str(tmp_path / "a"), **cfg))
    b = train(TrainConfig(out=str(tmp_path / "b"), **cfg))
    c = train(TrainConfig(out=str(tmp_path / "c"), seed=1, **cfg))
    wa, wb, wc = (load_file(m / "model.safetensors") for m in (a, b, c))
    assert all(torch.equal(wa[k], wb[k]) for k in wa)
    assert not all(torch.equal(wa[k], wc[k]) for k in wa)
    assert json.loads((a / "train_config.json").read_text())["attention_kernel"] == "kernel"


def test_last_checkpoint_is_the_newest_complete_one(tmp_path, capsys):
    assert last_checkpoint(tmp_path / "absent") is None and last_checkpoint(tmp_path) is None
    for step, state in [(2, "{}"), (10, "{}"), (11, '{"global_st'), (12, None)]:
        (tmp_path / f"checkpoint-{step}").mkdir()
        if state is not None:
            (tmp_path / f"checkpoint-{step}" / "trainer_state.json").write_text(state)
    (tmp_path / "checkpoint-99").write_text("a file")
    (tmp_path / "checkpoint-final").mkdir()
    # by number, not by name (checkpoint-2 sorts after checkpoint-10 as text)
    assert last_checkpoint(tmp_path) == str(tmp_path / "checkpoint-10")
    err = capsys.readouterr().err
    assert "checkpoint-12 is incomplete" in err and "checkpoint-11 is incomplete" in err
    for step in (10, 2):
        (tmp_path / f"checkpoint-{step}" / "trainer_state.json").unlink()
    assert last_checkpoint(tmp_path) is None
    with pytest.raises(FileNotFoundError, match="no complete checkpoint.*: --overwrite to train"):
        train(TrainConfig(dataset="-", objective="ad", out=str(tmp_path), resume=True))
    with pytest.raises(FileNotFoundError, match="to resume from: train without --resume"):
        train(TrainConfig(dataset="-", objective="ad", out=str(tmp_path / "new"), resume=True))
    assert not (tmp_path / "new").exists()


def test_cli_train_and_its_errors(small_darkroom, tmp_path, capsys):
    out = tmp_path / "m"
    args = [
        "train",
        "--dataset",
        str(small_darkroom.root),
        "--objective",
        "ad",
        "--out",
        str(out),
        "--preset",
        "tiny",
        "--max-steps",
        "3",
        "--batch-size",
        "4",
        "--context-length",
        "20",
    ]
    assert main(args) == 0
    assert "model:" in capsys.readouterr().out and (out / "config.json").exists()
    assert main(args) == 1
    assert "--resume" in capsys.readouterr().err
    assert main([*args[:-1], "500", "--overwrite"]) == 1
    assert "longer than the shortest history" in capsys.readouterr().err


@pytest.mark.slow
def test_two_accelerate_processes_report_the_one_process_losses(small_darkroom, tmp_path):
    """CPU data parallel (committed config): the same global batch gives the same loss per step."""
    common = [
        "--dataset",
        str(small_darkroom.root),
        "--objective",
        "ad",
        "--preset",
        "tiny",
        "--max-steps",
        "4",
        "--batch-size",
        "8",
        "--context-length",
        "40",
        "--lr",
        "3e-3",
        "--logging-steps",
        "1",
    ]
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    assert main(["train", *common, "--out", str(tmp_path / "one")]) == 0
    launcher = [
        sys.executable,
        "-m",
        "accelerate.commands.launch",
        "--config_file",
        str(accelerate_config()),  # the one the package ships
        "--main_process_port",
        "29547",
    ]
    run = subprocess.run(
        # lhf as a program, saying at exit whether each rank's process group was destroyed
        [
            *launcher,
            str(REPO / "tests/launch_probe.py"),
            "train",
            *common,
            "--out",
            str(tmp_path / "two"),
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    for rank in (0, 1):  # a rank exiting with a live gloo group aborted or hung (SIGABRT in CI)
        assert f"rank {rank}: process group alive at exit: False" in run.stderr, run.stderr[-3000:]
    prov = json.loads((tmp_path / "two" / "train_config.json").read_text())
    assert prov["world_size"] == 2 and prov["per_device_batch_size"] == 4
    np.testing.assert_allclose(losses(tmp_path / "two"), losses(tmp_path / "one"), rtol=1e-4)


@pytest.mark.slow
@pytest.mark.metaworld
@pytest.mark.parametrize("objective", ["ad", "dicp"])
def test_continuous_actions_train_on_metaworld(tmp_path_factory, objective):
    pytest.importorskip("metaworld")
    from lhf_hf.collection import collect
    from lhf_hf.configs import CollectConfig

    root = tmp_path_factory.getbasetemp() / "mw-reach"
    ds = collect(
        CollectConfig("metaworld-reach", tasks="0", histories=2, steps=200, workers=1),
        root,
        progress=False,
        resume=root.exists(),
    )
    out = train(
        TrainConfig(
            dataset=str(root),
            objective=objective,
            out=str(tmp_path_factory.mktemp("m") / "m"),
            max_steps=60,
            **TINY,
        )
    )
    model = AutoModel.from_pretrained(out)
    assert (
        not model.config.discrete_actions
        and model.config.state_bins == 0
        and model.config.action_dim == 4
    )
    assert model.config.context_length == 40 and ds.env_id == "metaworld-reach"
    loss = losses(out)
    assert np.all(np.isfinite(loss)) and np.mean(loss[-2:]) < np.mean(loss[:2]), loss


def test_batches_are_always_full_and_never_above_the_windows(small_darkroom, tmp_path):
    base = dict(dataset=str(small_darkroom.root), objective="ad", out=str(tmp_path / "m"),
                preset="tiny", context_length=40)  # fmt: skip
    trainer, prov = build_trainer(TrainConfig(batch_size=1000, **base))
    assert prov["windows"] == 30 * (200 - 40 + 1)  # 4,830: not a multiple of 1,000
    sizes = [len(b["states"]) for b in trainer.get_train_dataloader()]
    assert sizes == [1000] * 4, sizes  # a pass of whole batches, no short last one
    with pytest.raises(ValueError, match=r"--batch-size 5000 is larger than the 4830 training"):
        build_trainer(TrainConfig(batch_size=5000, **base))


def test_weights_get_the_umask_mode(small_darkroom, tmp_path):
    """safetensors writes 0600 whatever the umask; the model's files follow the umask like every
    other file the project writes (a shared group folder can read them)."""
    from lhf_hf.utils.io import _UMASK

    out = train(TrainConfig(dataset=str(small_darkroom.root), objective="ad", out=str(tmp_path / "m"),
                            preset="tiny", context_length=40, batch_size=4, max_steps=2, save_steps=2))  # fmt: skip
    for f in [out / "model.safetensors", *out.glob("checkpoint-*/model.safetensors")]:
        assert f.stat().st_mode & 0o777 == 0o666 & ~_UMASK, f


def test_a_resumed_run_records_the_world_sizes_it_ran_with(small_darkroom, tmp_path):
    cfg = dict(dataset=str(small_darkroom.root), objective="ad", out=str(tmp_path / "m"),
               preset="tiny", context_length=40, batch_size=4, max_steps=4, save_steps=2)  # fmt: skip
    out = train(TrainConfig(**cfg))
    prov = json.loads((out / "train_config.json").read_text())
    assert prov["world_size"] == 1 and prov["world_sizes"] == [[0, 1]]
    # as if steps 0-2 had run under a 2-process launcher before an interruption: the resumed
    # stretch is recorded beside
    shutil.rmtree(out / "checkpoint-4")
    (out / "config.json").unlink()  # not finished: resumed from checkpoint-2
    ident = out / "checkpoint-2" / "lhf_train_identity.json"
    ident.write_text(json.dumps({**json.loads(ident.read_text()), "world_sizes": [[0, 2]]}))
    train(TrainConfig(**cfg, resume=True))
    prov = json.loads((out / "train_config.json").read_text())
    assert prov["world_sizes"] == [[0, 2], [2, 1]] and prov["world_size"] == 1


def test_rotation_keeps_checkpoints_holding_what_training_did_not_write(tmp_path, capsys):
    """The newest two checkpoints stay, older ones go, except one holding a user's file or a
    nested evaluation (Trainer's own rotation deletes whatever a checkpoint folder holds)."""
    from types import SimpleNamespace

    from lhf_hf.training.trainer import RotateOwnCheckpoints

    for step in (1, 2, 3, 4):
        (tmp_path / f"checkpoint-{step}").mkdir()
        for name in ("config.json", "model.safetensors", "optimizer.pt", "trainer_state.json"):
            (tmp_path / f"checkpoint-{step}" / name).write_text("x")
    (tmp_path / "checkpoint-1" / "notes.txt").write_text("mine")
    (tmp_path / "checkpoint-2" / "rng_state.pth").write_text("x")
    for name in MODEL_CODE_FILES:  # the model's code: written by training too
        (tmp_path / "checkpoint-2" / name).write_text("x")
    RotateOwnCheckpoints().on_save(
        SimpleNamespace(output_dir=str(tmp_path)), SimpleNamespace(is_world_process_zero=True), None
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "checkpoint-1",
        "checkpoint-3",
        "checkpoint-4",
    ]
    assert (tmp_path / "checkpoint-1" / "notes.txt").read_text() == "mine"
    assert "checkpoint-1 is kept (it holds notes.txt" in capsys.readouterr().err


def test_resume_refuses_an_edited_checkpoint_config_and_does_nothing_on_a_finished_run(
    small_darkroom, tmp_path, capsys
):
    cfg = dict(dataset=str(small_darkroom.root), objective="ad", out=str(tmp_path / "m"),
               preset="tiny", context_length=40, batch_size=4, save_steps=2, max_steps=2)  # fmt: skip
    out = train(TrainConfig(**cfg))
    weights = (out / "model.safetensors").read_bytes()
    train(TrainConfig(**cfg, resume=True))  # finished: nothing to resume, nothing rewritten
    assert "is finished (step 2 of 2): nothing to resume" in capsys.readouterr().err
    assert (out / "model.safetensors").read_bytes() == weights
    assert json.loads((out / "train_config.json").read_text())["global_step"] == 2
    conf = out / "checkpoint-2" / "config.json"
    conf.write_text(json.dumps({**json.loads(conf.read_text()), "objective": "dicp"}))
    with pytest.raises(
        ValueError, match=r"config.json does not describe this run's model \(objective: 'dicp'"
    ):
        train(TrainConfig(**cfg, resume=True))


def test_a_diverged_training_writes_no_model(small_darkroom, tmp_path):
    cfg = TrainConfig(dataset=str(small_darkroom.root), objective="ad", out=str(tmp_path / "m"),
                      preset="tiny", context_length=40, batch_size=4, max_steps=2, lr=1e308)  # fmt: skip
    with pytest.raises(ValueError, match="training diverged: .* NaN or infinite"):
        train(cfg)
    assert not (tmp_path / "m" / "model.safetensors").exists()


def test_every_saved_folder_carries_the_model_code(small_darkroom, tmp_path):
    """The final model and every checkpoint-N: config.json's auto_map and the files it names, the
    bundle of this lhf_hf (transformers alone loads them: tests/modeling/test_transformers_only.py)."""
    cfg = TrainConfig(dataset=str(small_darkroom.root), objective="ad", out=str(tmp_path / "m"),
                      preset="tiny", context_length=40, batch_size=4, save_steps=1, max_steps=2)  # fmt: skip
    out = train(cfg, progress=False)
    code = model_code()
    for folder in (out, out / "checkpoint-1", out / "checkpoint-2"):
        assert json.loads((folder / "config.json").read_text())["auto_map"] == AUTO_MAP
        assert {p.name: p.read_text() for p in folder.glob("*.py")} == code, folder
