"""Configuration of ``lhf train`` (docs/design.md 6; paper appendix "Transformer Models")."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from lhf_hf.constants import Objective
from lhf_hf.errors import UserError
from lhf_hf.utils.hub import validate_repo_id

from .model import (
    Attention,
    LabelPositions,
    ModelPreset,
    RewardWeighting,
    StateEncoding,
    check_model_fields,
)
from .types import check_types


@dataclass(frozen=True)
class TrainConfig:
    """How to pretrain one ICRL model.  Stored as ``train_config.json`` beside the weights.

    dataset: learning-history dataset folder (``lhf collect`` / ``lhf filter --materialize``).
    objective: ``ad``, ``dpt`` or ``dicp`` (paper appendix "Backbone ICRL Algorithms").
    out: output folder (checkpoints, final weights, card).
    selection: optional LHF selection folder (``lhf filter``): histories are drawn with its counts.
    preset: backbone size: ``paper`` (4/4/32/128), ``lightweight`` (2/2/16/64) or ``tiny`` (tests).
    max_steps: optimiser steps (the reference: 50,000 at batch 512 on a GPU).
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
        source's); None = ``actions`` where it applies (DICP, discrete actions, reward classes),
        else ``data``.  Measured on Darkroom in docs/evaluation.md.
    seed: seeds the model init, dropout and the window sampler (every process gets the same seed).
    save_steps: checkpoint interval (resumable with ``resume``).
    logging_steps: loss log interval.
    resume: continue from the last checkpoint in ``out``.
    overwrite: start afresh in an ``out`` that already holds checkpoints or a model.
    push_to_hub: a model repo id ``ORG/NAME``: Trainer pushes every saved checkpoint's weights
        there during training and the final folder (weights, config, train config, card) at the end.
    hub_private: create that repo private.
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

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        return cls(**d)
