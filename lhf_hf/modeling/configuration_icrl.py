"""``ICRLConfig``: one LlamaConfig-based configuration for AD, DPT and DICP (docs/design.md 6).

The backbone is ``transformers.LlamaModel`` fed through ``inputs_embeds``; this config adds what the
ICRL model around it needs: the objective, the environment's state and action spaces, the context
length in transitions, the label positions, the DICP dynamics weight xi and the planning settings.
Paper sizes are in ``lhf_hf.configs.model.PRESETS`` (appendix "Transformer Models", Table "Key hyperparameters"),
with the field rules ``TrainConfig`` shares.
"""

from __future__ import annotations

from huggingface_hub.dataclasses import strict
from transformers import LlamaConfig

from lhf_hf.configs.model import (
    ATTENTIONS,
    MAX_CELLS,
    PRESETS,
    REWARD_WEIGHTINGS,
    STATE_ENCODINGS,
    check_model_fields,
)
from lhf_hf.errors import UserError

#: The parts of a transition token's feature vector, in order (``modeling_icrl`` module docstring):
#: the step before (all zero where there is none) and the state the next action is taken from.
TRANSITION_FEATURES = ("prev_state", "prev_action", "prev_reward", "prev_done", "has_prev", "state")
#: The parts of a DICP query-action token's feature vector, in order: a state and the action taken in it.
QUERY_FEATURES = ("state", "action")


@strict
class ICRLConfig(LlamaConfig):
    r"""Configuration of an in-context RL transformer (``model_type = "lhf_icrl"``).

    All LlamaConfig fields apply to the backbone.  Added fields:

    objective: ``ad`` (imitate the source action), ``dpt`` (predict the oracle's optimal action) or
        ``dicp`` (AD plus reward / next-state / return-to-go heads, paper appendix "DICP").
    env_id: the environment the model was trained for (checked again at evaluation).
    train_tasks: the task indices of the training data (set by ``lhf train``; None: not recorded).
        ``lhf evaluate`` refuses these tasks unless asked (``--allow-seen``): they are not unseen.
    split_seed: the train/test split seed of the training data (set by ``lhf train``): the
        evaluation's default split, and, where the task content depends on it
        (``EnvSpec.seeded_tasks``), part of what makes a task the same as a trained one.
    state_dim: length of the state vector.
    state_bins: 0 for real-valued states; otherwise every state coordinate is an integer in
        ``[0, state_bins)`` (the gridworlds): it is one-hot encoded at the input and predicted by a
        categorical head per coordinate (DICP).
    state_encoding: how integer states enter and leave the model: ``coordinates`` (one-hot per
        coordinate; the next-state head classifies each coordinate) or ``cells`` (one-hot over the
        ``state_bins ** state_dim`` cells; the next-state head is one class over the cells: the
        reference DICP's query-state embedding and 81-way next-state head).  Ignored for real-valued
        states.
    action_dim: number of actions (discrete) or action dimensions (continuous).
    discrete_actions: categorical action head when True, Gaussian head with learned log-std when False.
    context_length: transitions the model sees (darkroom 80, other gridworlds 200, Meta-World 1000).
    attention: what a token attends to, which decides how the model is evaluated
        (``lhf_hf.evaluation.context``): ``window`` (trained on windows of ``context_length``
        transitions with causal attention, the reference's: evaluated by re-encoding the last
        window at every step) or ``band`` (trained on longer sequences where every token attends to
        the tokens of the last ``context_length`` transitions in every layer: evaluated with the
        streaming KV cache, which computes exactly that function).
    label_positions: ``all``: an action label at every position (each token carries the state the
        next action is taken from); ``query``: only at the last position, as the reference AD does.
        DPT always labels every position (its loss is over every prefix).
    dynamics_coef: xi, the weight of the DICP dynamics losses.
    return_scale: return-to-go targets are divided by this (the episode horizon), so that its squared
        error is on the scale of the reward's.
    embedding_dropout: dropout on the token embeddings; with ``attention_dropout`` this is the
        paper's "attention dropout & dropout" (LlamaModel has no residual dropout of its own).
    reward_values: the rewards a step can give, when they are few (increasing; the env's
        ``EnvSpec.reward_values``): DICP's reward head is then a classifier over them (cross-entropy,
        as the reference's), and the predicted reward is the most likely class's value; None: a
        regression head (squared error), for real-valued rewards.
    reward_weighting: how DICP's reward loss weighs the positions: ``data`` (as the histories hold
        them) or ``actions`` (reward classes and discrete actions only): each position is weighted by
        ``1 / (A * p(a | c))``, where ``p(a | c)`` is the frequency of its action among the batch's
        positions whose previous step's reward is in the same class ``c``, so that within each class
        every action weighs the same.  Why: the planner asks the reward head about every action
        from every state, while the source agents, once on the goal, almost always stay; the
        unweighted loss lets the head learn "rewarded if the previous step was" and imagine rewards
        for moves that leave the goal (docs/evaluation.md).
    plan_beams / plan_horizon / plan_samples: DICP planning (beams and depth of the discrete beam
        search; candidates of the continuous greedy search: the policy mean plus samples).
    """

    model_type = "lhf_icrl"

    objective: str = "ad"
    env_id: str | None = None
    train_tasks: list[int] | None = None
    split_seed: int | None = None
    state_dim: int = 2
    state_bins: int = 0
    state_encoding: str = "coordinates"
    attention: str = "window"
    action_dim: int = 5
    discrete_actions: bool = True
    context_length: int = 80
    label_positions: str = "all"
    dynamics_coef: float = 1.0
    return_scale: float = 1.0
    embedding_dropout: float = 0.1
    plan_beams: int = 10
    plan_horizon: int = 8
    plan_samples: int = 10
    reward_values: list[float] | None = None
    reward_weighting: str = "data"

    # LlamaConfig defaults that make no sense without a vocabulary.
    vocab_size: int = 1
    hidden_size: int = 32
    intermediate_size: int = 128
    num_hidden_layers: int = 4
    num_attention_heads: int = 4
    attention_dropout: int | float | None = 0.1
    max_position_embeddings: int = 4096
    bos_token_id: int | None = None
    eos_token_id: int | list[int] | None = None
    pad_token_id: int | None = None

    def __post_init__(self, **kwargs):
        def bad(field: str, why: str):
            return UserError(f"ICRLConfig.{field} {why}, got {getattr(self, field)!r}")

        check_model_fields(
            "ICRLConfig",
            objective=self.objective,
            label_positions=self.label_positions,
            context_length=self.context_length,
            dynamics_coef=self.dynamics_coef,
        )
        rv = self.reward_values
        if rv is not None and (
            len(rv) < 2 or any(b <= a for a, b in zip(rv, rv[1:], strict=False))
        ):
            raise bad("reward_values", "must be None or >= 2 increasing values")
        for name in ("state_dim", "action_dim", "plan_beams", "plan_horizon"):
            if getattr(self, name) < 1:
                raise bad(name, "must be >= 1")
        if self.state_bins < 0 or self.state_bins == 1:
            raise bad("state_bins", "must be 0 (real-valued states) or >= 2")
        if self.attention not in ATTENTIONS:
            raise bad("attention", f"must be one of {ATTENTIONS}")
        if self.reward_weighting not in REWARD_WEIGHTINGS:
            raise bad("reward_weighting", f"must be one of {REWARD_WEIGHTINGS}")
        if self.reward_weighting == "actions" and not (
            self.objective == "dicp" and self.discrete_actions and rv
        ):
            raise bad(
                "reward_weighting",
                "'actions' is for DICP with discrete actions and reward classes (reward_values)",
            )
        if self.state_encoding not in STATE_ENCODINGS:
            raise bad("state_encoding", f"must be one of {STATE_ENCODINGS}")
        if self.state_encoding == "cells" and self.state_bins and self.cells > MAX_CELLS:
            raise bad(
                "state_encoding",
                f"'cells' needs state_bins ** state_dim <= {MAX_CELLS} "
                f"({self.state_bins} ** {self.state_dim} = {self.cells}); use 'coordinates'",
            )
        if self.discrete_actions and self.action_dim < 2:
            raise bad("action_dim", "must be >= 2 for a discrete action space")
        if self.return_scale <= 0:
            raise bad("return_scale", "must be > 0")
        if not 0 <= self.embedding_dropout < 1:
            raise bad("embedding_dropout", "must be in [0, 1)")
        if self.train_tasks is not None and any(t < 0 for t in self.train_tasks):
            raise bad("train_tasks", "must be None or task indices >= 0")
        if self.split_seed is not None and self.split_seed < 0:
            raise bad("split_seed", "must be None or >= 0")
        if self.plan_samples < 1:
            raise bad("plan_samples", "must be >= 1")
        super().__post_init__(**kwargs)

    @property
    def cells(self) -> int:
        """Number of distinct integer states (``state_bins ** state_dim``), 0 for real states."""
        return self.state_bins**self.state_dim if self.state_bins else 0

    @property
    def cell_encoded(self) -> bool:
        """Integer states encoded as one cell one-hot (``state_encoding == "cells"``)."""
        return bool(self.state_bins) and self.state_encoding == "cells"

    @property
    def state_features(self) -> int:
        """Width of an encoded state: ``cells`` (one cell one-hot), ``state_dim * state_bins`` (one-hot
        per coordinate) or ``state_dim`` (real-valued states as they are)."""
        if self.cell_encoded:
            return self.cells
        return self.state_dim * self.state_bins if self.state_bins else self.state_dim

    def _feature_slices(self, parts: tuple[str, ...]) -> dict[str, slice]:
        widths = {"action": self.action_dim, "reward": 1, "done": 1, "has_prev": 1}
        widths["state"] = self.state_features
        layout, start = {}, 0
        for name in parts:
            width = widths[name.removeprefix("prev_")]
            layout[name] = slice(start, start + width)
            start += width
        return layout

    @property
    def transition_layout(self) -> dict[str, slice]:
        """Where each part of ``TRANSITION_FEATURES`` lies in a transition token's feature vector,
        in order; the last slice's stop is the vector's width.  The one definition of the layout:
        the model's embedder (``ICRLModel.transition_features``) and the rollout's numpy embedder
        (``lhf_hf.evaluation.tokens``) both build their vectors from it."""
        return self._feature_slices(TRANSITION_FEATURES)

    @property
    def query_layout(self) -> dict[str, slice] | None:
        """As ``transition_layout``, for DICP's query-action token (``QUERY_FEATURES``); None for
        the objectives without one."""
        return self._feature_slices(QUERY_FEATURES) if self.objective == "dicp" else None

    @property
    def tokens_per_transition(self) -> int:
        """DICP interleaves a query-action token after every transition token."""
        return 2 if self.objective == "dicp" else 1

    @property
    def max_tokens(self) -> int:
        """Tokens of a window of ``context_length`` transitions."""
        return self.context_length * self.tokens_per_transition


def icrl_config(preset: str = "paper", **fields) -> ICRLConfig:
    """An ``ICRLConfig`` with the backbone sizes of ``preset`` and the given fields."""
    if preset not in PRESETS:
        raise UserError(f"unknown model preset {preset!r}; choose one of {sorted(PRESETS)}")
    return ICRLConfig(**{**PRESETS[preset], **fields})
