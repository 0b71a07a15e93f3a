"""Configuration of ``lhf train`` (docs/design.md 6; paper appendix "Transformer Models")."""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from typing import Any

from lhf_hf.constants import Objective
from lhf_hf.errors import UserError
from lhf_hf.utils.hub import validate_repo_id

from .model import (
    Attention,
    AttentionKernel,
    LabelPositions,
    ModelPreset,
    RewardWeighting,
    StateEncoding,
    check_model_fields,
)
from .types import check_types

#: optimiser steps: 20 times the reference's 50,000, so that a mistyped count fails here, not after
#: days; the trainer's log history (in memory and ``trainer_state.json``) grows with every step logged.
MAX_STEPS = 1_000_000
#: ``TrainingArguments`` fields that lhf sets from its own flags: ``training_args`` refuses them
#: and names the flag (one place per setting).
TRAINING_ARGS_FROM_FLAGS = {
    "output_dir": "--out",
    "max_steps": "--max-steps",
    "num_train_epochs": "--max-steps",
    "per_device_train_batch_size": "--batch-size (the global batch, split across processes)",
    "learning_rate": "--lr",
    "warmup_steps": "--warmup-steps",
    "weight_decay": "--weight-decay",
    "adam_beta1": "--beta1",
    "adam_beta2": "--beta2",
    "max_grad_norm": "--max-grad-norm",
    "logging_steps": "--logging-steps",
    "save_steps": "--save-steps",
    "seed": "--seed",
    "report_to": "--report-to",
    "disable_tqdm": "--no-progress",
    "push_to_hub": "--push-to-hub",
    "hub_model_id": "--push-to-hub",
    "hub_private_repo": "--hub-private",
    "resume_from_checkpoint": "--resume",
}
#: ``TrainingArguments`` fields that lhf fixes, and why: another value would break what the
#: flags promise.
TRAINING_ARGS_FIXED = {
    "save_total_limit": "lhf keeps the newest 2 checkpoints itself (and any holding files "
    "training did not write)",
    "remove_unused_columns": "the window collators read every column",
    "dataloader_drop_last": "the sampler draws whole batches, so no step is short",
    "gradient_accumulation_steps": "--batch-size is the windows of one optimiser step",
    "auto_find_batch_size": "--batch-size is the windows of one optimiser step",
    "hub_strategy": "lhf pushes each saved checkpoint itself (--push-to-hub)",
}


@dataclass(frozen=True)
class TrainConfig:
    """How to pretrain one ICRL model.  Stored as ``train_config.json`` beside the weights.

    dataset: learning-history dataset (``lhf collect`` / ``lhf filter --materialize``): a folder
        or a Hub dataset repo ``ORG/NAME[@REV]``.
    objective: ``ad``, ``dpt`` or ``dicp`` (paper appendix "Backbone ICRL Algorithms").
    out: output folder (checkpoints, final weights, card).
    selection: optional LHF selection (``lhf filter``), a folder or a Hub repo ``ORG/NAME[@REV]``:
        histories are drawn with its counts.
    preset: backbone size: ``paper`` (4/4/32/128), ``lightweight`` (2/2/16/64) or ``tiny`` (tests).
    max_steps: optimiser steps (the reference: 50,000 at batch 512 on a GPU; at most 1,000,000).
    batch_size: windows per optimiser step over all processes (split evenly across them).
    context_length: transitions per window; None = the env's default (Darkroom 80, the other
        gridworlds 200, Meta-World 1000).
    label_positions: ``all`` (a label at every position) or ``query`` (last position only, as the
        reference AD); None = ``all``.
    attention: ``window`` (windows of ``context_length`` transitions, causal attention: the
        reference's; evaluated by re-encoding the last window) or ``band`` (sequences of
        ``sequence_length`` transitions where every token attends to the last ``context_length``
        transitions' tokens; evaluated with the streaming KV cache, the same function).
        docs/training.md compares the two (windows learn more per CPU-minute on Darkroom).
    sequence_length: transitions per training sequence with ``attention="band"``; None = 4 x the
        context length.
    attention_kernel: which code computes attention in training: ``kernel`` (a C++ kernel, built
        with the system's compiler on first use: scores, mask, softmax, dropout and the value
        product fused per head, forward and backward), ``torch`` (torch ops, ``lhf_sdpa``) or
        ``auto`` (the kernel where it builds and runs: CPU training, head dim 8 or 16; else torch).
        The two draw different dropout masks from the seed, so the value that ran is recorded
        (``lhf_train_identity.json``, the provenance's ``attention_kernel``).
    lr: peak learning rate (paper 1e-2), cosine decay to 0 after ``warmup_steps`` of linear warm-up.
    warmup_steps: steps of linear learning-rate warm-up from 0 (the paper's GPU runs: 1,000).
    weight_decay: AdamW weight decay (paper 0.01).
    beta1: AdamW beta1 (paper 0.9).
    beta2: AdamW beta2 (paper 0.99).
    max_grad_norm: gradient clipping norm (paper 1).
    dynamics_coef: xi, the DICP dynamics loss weight.
    state_encoding: integer (grid) states as ``coordinates`` (one-hot per coordinate; DICP predicts
        each coordinate) or ``cells`` (one-hot over the grid's cells; DICP predicts the next cell as
        one class, the reference's encoding); real-valued states are used as they are.  Measured on
        Darkroom (docs/training.md): coordinates learn faster at the cpu budget.
    reward_weighting: how DICP's reward loss weighs positions: ``data`` (as the histories hold
        them) or ``actions`` (every action alike within each class of the previous step's reward,
        so the reward head learns what the planner asks: the reward of any action, not only of the
        source's; a variant of ours, measured on Darkroom in docs/evaluation.md); None = ``data``,
        the reference's (jaehyeon-son/dicp).
    seed: seeds the model init, dropout and the window sampler (every process gets the same seed).
    save_steps: checkpoint interval (resumable with ``resume``).
    logging_steps: loss log interval.
    resume: continue from the last checkpoint in ``out``.
    overwrite: start afresh in an ``out`` that already holds checkpoints or a model.
    push_to_hub: a model repo id ``ORG/NAME``: Trainer pushes every saved checkpoint's weights
        there during training and the final folder (weights, config, train config, card) at the end.
    hub_private: create that repo private.
    report_to: where Trainer reports its logs, as ``TrainingArguments.report_to``: ``none``,
        ``all`` (every installed integration) or integration names, comma-separated
        (``tensorboard``, ``trackio``, ``wandb``, ``mlflow``, ...); a named one must be installed.
    training_args: other ``transformers.TrainingArguments`` fields, ``KEY=VALUE`` (repeatable;
        e.g. ``lr_scheduler_type=linear``, ``adam_epsilon=1e-6``), each value read as its field's
        type; the fields lhf sets from its own flags are refused with the flag to use.
    """

    dataset: str
    objective: Objective
    out: str
    selection: str | None = None
    preset: ModelPreset = "paper"
    max_steps: int = 2000
    batch_size: int = 64
    context_length: int | None = None
    label_positions: LabelPositions | None = None
    attention: Attention = "window"
    sequence_length: int | None = None
    attention_kernel: AttentionKernel = "auto"
    lr: float = 1e-2
    warmup_steps: int = 0
    weight_decay: float = 0.01
    beta1: float = 0.9
    beta2: float = 0.99
    max_grad_norm: float = 1.0
    dynamics_coef: float = 1.0
    state_encoding: StateEncoding = "coordinates"
    reward_weighting: RewardWeighting | None = None
    seed: int = 0
    save_steps: int = 500
    logging_steps: int = 50
    resume: bool = False
    overwrite: bool = False
    push_to_hub: str | None = None
    hub_private: bool = False
    report_to: str | list[str] = "none"
    training_args: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_types(self)

        def bad(field: str, why: str):
            return UserError(f"TrainConfig.{field} {why}, got {getattr(self, field)!r}")

        # the model's own fields: ICRLConfig's rules (configs/model.py), checked before anything loads
        check_model_fields(
            "TrainConfig",
            objective=self.objective,
            label_positions=self.label_positions,
            context_length=self.context_length,
            dynamics_coef=self.dynamics_coef,
            preset=self.preset,
        )
        for name in ("max_steps", "batch_size", "save_steps", "logging_steps"):
            if getattr(self, name) < 1:
                raise bad(name, "must be >= 1")
        if self.max_steps > MAX_STEPS:
            raise bad(
                "max_steps",
                f"(--max-steps) must be at most {MAX_STEPS:,} (20 times the reference's 50,000; "
                "the trainer keeps a log entry per --logging-steps steps, in memory and in "
                "trainer_state.json)",
            )
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise bad("lr", "must be > 0")
        if self.seed < 0:
            raise bad("seed", "must be >= 0")
        if self.warmup_steps < 0 or self.warmup_steps >= self.max_steps:
            raise bad("warmup_steps", f"must be in [0, max_steps={self.max_steps})")
        if not self.weight_decay >= 0:
            raise bad("weight_decay", "must be >= 0")
        if not self.max_grad_norm > 0:
            raise bad("max_grad_norm", "must be > 0")
        if self.sequence_length is not None:
            if self.attention != "band":
                raise bad("sequence_length", "is for attention='band' only")
            if self.sequence_length < (self.context_length or 1):
                raise bad("sequence_length", f"must be >= context_length={self.context_length}")
        if self.attention == "band" and self.label_positions == "query":
            raise bad("label_positions", "must be 'all' with attention='band'")
        if self.resume and self.overwrite:
            raise UserError("TrainConfig: resume and overwrite exclude each other")
        for name in ("beta1", "beta2"):
            if not 0 <= getattr(self, name) < 1:
                raise bad(name, "must be in [0, 1)")
        if self.push_to_hub is not None:
            validate_repo_id(self.push_to_hub)
        reporters = self.reporters
        if not reporters or any(not re.fullmatch(r"[a-z][a-z0-9_]*", r) for r in reporters):
            raise bad("report_to", "must be 'none', 'all' or integration names, comma-separated")
        if len(reporters) > 1 and {"none", "all"} & set(reporters):
            raise bad("report_to", "names 'none' or 'all' alone")
        for key in self.training_args:
            check_training_arg(key)

    @property
    def reporters(self) -> list[str]:
        """``report_to`` as a list of names (``"tensorboard,wandb"`` -> both)."""
        given = [self.report_to] if isinstance(self.report_to, str) else self.report_to
        return [n.strip() for item in given for n in item.split(",") if n.strip()]

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        return cls(**d)


def check_training_arg(key: Any) -> None:
    """Refuse a ``training_args`` key that lhf sets from a flag or fixes (the rest are checked
    against ``TrainingArguments`` itself when training starts, ``training.arguments``)."""
    where = f"TrainConfig.training_args: {key!r}"
    if not isinstance(key, str) or not key.isidentifier():
        raise UserError(f"{where} is not a TrainingArguments field name")
    if key in TRAINING_ARGS_FROM_FLAGS:
        raise UserError(f"{where} is set by lhf's own flag: use {TRAINING_ARGS_FROM_FLAGS[key]}")
    if key in TRAINING_ARGS_FIXED:
        raise UserError(f"{where} is fixed by lhf: {TRAINING_ARGS_FIXED[key]}")
