"""What an ICRL model's fields may be: the backbone presets and the rules that tie the objective,
label positions, context and dynamics weight together.

Imports nothing heavy (no transformers), so that ``TrainConfig``, which the CLI builds before
anything loads, checks the model fields with the rules ``ICRLConfig`` (``lhf_hf.modeling``) applies:
written once, here.
"""

from __future__ import annotations

from typing import Literal, get_args

from lhf_hf.constants import OBJECTIVES
from lhf_hf.errors import UserError

LabelPositions = Literal["all", "query"]
LABEL_POSITIONS: tuple[str, ...] = get_args(LabelPositions)

ModelPreset = Literal["paper", "lightweight", "tiny"]

# How integer (grid) states are encoded: one-hot per coordinate, or one-hot over the grid's cells
# (ICRLConfig's docstring says why cells).  MAX_CELLS bounds the cell one-hot's width.
StateEncoding = Literal["cells", "coordinates"]
STATE_ENCODINGS: tuple[str, ...] = get_args(StateEncoding)
MAX_CELLS = 4096

# How DICP's reward loss weighs its positions (ICRLConfig.reward_weighting): "data" = as the histories
# hold them; "actions" = importance weights that make the actions uniform within each class of the
# previous step's reward (the planner asks about every action; docs/evaluation.md says why).
RewardWeighting = Literal["data", "actions"]
REWARD_WEIGHTINGS: tuple[str, ...] = get_args(RewardWeighting)

# What a token attends to (ICRLConfig.attention): "window" = causal attention within a training
# window of K transitions (the reference's; evaluated by re-encoding the last window); "band" =
# every token attends to the last K transitions' tokens in every layer, trained on longer sequences
# (evaluated with the streaming KV cache, the same function).
Attention = Literal["window", "band"]
ATTENTIONS: tuple[str, ...] = get_args(Attention)

# Which code computes the training attention (TrainConfig.attention_kernel): "kernel" = the C++
# kernel (lhf_hf/modeling/attention_kernel.py: fused, dropout mask from a counter-based hash);
# "torch" = torch ops (lhf_sdpa, lhf_hf/modeling/train_attention.py); "auto" = the kernel where it
# builds and runs (CPU, head dim 8 or 16), else torch.  The two draw different dropout masks, so the
# resolved value is part of a training's identity.
AttentionKernel = Literal["auto", "kernel", "torch"]
ATTENTION_KERNELS: tuple[str, ...] = get_args(AttentionKernel)

# Backbone sizes.  "paper": the paper's table (4 layers, 4 heads, embedding 32, intermediate 128,
# dropout 0.1); "lightweight": appendix "ICRL with lightweight models" (2/2/16/64); "tiny": tests.
PRESETS: dict[str, dict] = {
    "paper": dict(
        num_hidden_layers=4,
        num_attention_heads=4,
        hidden_size=32,
        intermediate_size=128,
        attention_dropout=0.1,
        embedding_dropout=0.1,
    ),
    "lightweight": dict(
        num_hidden_layers=2,
        num_attention_heads=2,
        hidden_size=16,
        intermediate_size=64,
        attention_dropout=0.1,
        embedding_dropout=0.1,
    ),
    "tiny": dict(
        num_hidden_layers=1,
        num_attention_heads=2,
        hidden_size=16,
        intermediate_size=32,
        attention_dropout=0.0,
        embedding_dropout=0.0,
    ),
}
assert tuple(PRESETS) == get_args(ModelPreset)


def check_model_fields(
    owner: str,
    *,
    objective: str,
    label_positions: str | None = None,
    context_length: int | None = None,
    dynamics_coef: float | None = None,
    preset: str | None = None,
) -> None:
    """Raise ``UserError("<owner>.<field> ...")`` where a model field breaks a rule.  ``None``
    means "not set here" (e.g. ``TrainConfig``'s context length defaults to the env's)."""

    def bad(field: str, value, why: str) -> ValueError:
        return UserError(f"{owner}.{field} {why}, got {value!r}")

    if objective not in OBJECTIVES:
        raise bad("objective", objective, f"must be one of {OBJECTIVES}")
    if preset is not None and preset not in PRESETS:
        raise bad("preset", preset, f"must be one of {tuple(PRESETS)}")
    if label_positions is not None:
        if label_positions not in LABEL_POSITIONS:
            raise bad("label_positions", label_positions, f"must be one of {LABEL_POSITIONS}")
        if objective == "dpt" and label_positions != "all":
            # DPT's loss is over every prefix of the context (DPT paper, eq. 1).
            raise bad(
                "label_positions",
                label_positions,
                "must be 'all' for DPT (its loss is over every prefix)",
            )
    if context_length is not None and context_length < 1:
        raise bad("context_length", context_length, "must be >= 1")
    if dynamics_coef is not None and not dynamics_coef >= 0:
        raise bad("dynamics_coef", dynamics_coef, "must be >= 0")
