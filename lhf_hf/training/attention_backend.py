"""Which code computes a training's attention (``TrainConfig.attention_kernel``), resolved once
before training and recorded: the C++ kernel (``lhf_hf.modeling.attention_kernel``) and the torch
path (``lhf_sdpa``) draw different dropout masks from the same seed, so a run's identity names the
one that ran (a past issue: the PPO backend, ``lhf_hf.collection.backend_verdict``)."""

from __future__ import annotations

import logging

import torch

from lhf_hf.configs.model import PRESETS
from lhf_hf.configs.train import TrainConfig
from lhf_hf.errors import UserError
from lhf_hf.modeling import ICRLConfig, attention_kernel
from lhf_hf.modeling.train_attention import NAME as TORCH_ATTENTION

from .arguments import parse_training_args

logger = logging.getLogger(__name__)


def kernel_unsupported(config: ICRLConfig, device: torch.device) -> str | None:
    """Why the kernel cannot train this model here (None when it can)."""
    if device.type != "cpu":
        return f"the attention kernel runs on the CPU (training runs on {device.type})"
    head_dim = config.hidden_size // config.num_attention_heads
    if head_dim not in attention_kernel.HEAD_DIMS:
        return f"the attention kernel has head dims {attention_kernel.HEAD_DIMS}, this model {head_dim}"
    if config.dtype not in (None, torch.float32, "float32"):
        return f"the attention kernel computes in float32 (the model is {config.dtype})"
    return attention_kernel.available()


def _autocast(training_args: dict) -> str | None:
    """The mixed-precision Trainer argument set (``bf16``, ``fp16``), if any: the kernel leaves
    autocast to the torch path."""
    return next((k for k in ("bf16", "fp16") if training_args.get(k)), None)


def resolve_attention_kernel(cfg: TrainConfig, config: ICRLConfig, device: torch.device) -> str:
    """``kernel`` or ``torch``: ``cfg.attention_kernel`` with ``auto`` decided (a UserError when
    ``kernel`` is asked for and cannot run)."""
    if cfg.attention_kernel == "torch":
        return "torch"
    chosen = config._attn_implementation
    if chosen not in (None, TORCH_ATTENTION, attention_kernel.NAME):
        # a model config that names another attention (icrl_config(attn_implementation="sdpa")):
        # the caller's choice, torch code
        if cfg.attention_kernel == "kernel":
            raise UserError(
                f"TrainConfig.attention_kernel='kernel', but the model config asks for "
                f"attn_implementation={chosen!r}"
            )
        return "torch"
    mixed = _autocast(cfg.training_args)
    why = (
        f"training_args {mixed}=True computes attention in autocast, which the kernel leaves to torch"
        if mixed
        else kernel_unsupported(config, device)
    )
    if why is None:
        return "kernel"
    if cfg.attention_kernel == "kernel":
        raise UserError(f"TrainConfig.attention_kernel='kernel': {why}; use 'torch' or 'auto'")
    logger.info("attention_kernel=auto: the torch path trains (%s)", why)
    return "torch"


def use_attention(model: torch.nn.Module, backend: str) -> None:
    """Make ``model`` (an ``ICRLModel``) compute attention with ``backend`` (``kernel`` or
    ``torch``; another implementation the model config named is left as it is).  The choice is not
    saved in ``config.json`` (transformers does not serialise it): a loaded checkpoint attends with
    the default ``lhf_sdpa``, the same function without dropout."""
    if model.config._attn_implementation in (TORCH_ATTENTION, attention_kernel.NAME):
        model.config._attn_implementation = (
            attention_kernel.NAME if backend == "kernel" else TORCH_ATTENTION
        )


def planned_attention_kernel(cfg: TrainConfig) -> str:
    """``cfg.attention_kernel`` decided before the data exist, by ``resolve_attention_kernel``'s
    rules for a model of ``cfg.preset`` (``lhf reproduce`` names a training stage by it: the two
    paths' masks differ, so a cached stage must say which one trained it)."""
    if cfg.attention_kernel != "auto":
        return cfg.attention_kernel
    args = parse_training_args(cfg.training_args)
    size = PRESETS[cfg.preset]
    head_dim = size["hidden_size"] // size["num_attention_heads"]
    if (
        _autocast(args)
        or torch.cuda.is_available()  # training runs on the GPU: the torch path
        or head_dim not in attention_kernel.HEAD_DIMS
    ):
        return "torch"
    return "kernel" if attention_kernel.available() is None else "torch"
