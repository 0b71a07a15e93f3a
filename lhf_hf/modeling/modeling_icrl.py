"""ICRL transformer for AD, DPT and DICP: token embedders and heads around ``LlamaModel`` (docs/design.md 6).

Token layout (one token per transition, state first).  Token ``j`` of a window embeds

    [prev_state s_{j-1}, prev_action a_{j-1}, prev_reward r_{j-1}, prev_done d_{j-1}, has_prev, state s_j]

(``ICRLConfig.transition_layout``: where each part lies, the one definition every embedder follows)

where ``s_j`` is the state the next action is taken from: inside an episode ``s_j`` is the previous
transition's next state; after an episode end it is the new episode's start state (the true final
state stays a DICP target, never an input).  Every token is therefore a query for ``a_j``: AD labels
the source action, DPT the oracle's optimal action, at every position (paper eq. "AD", "DPT": a sum
over t of log M(a_t | C_{t-1}, s_t)) or, with ``label_positions="query"``, at the last one only (the
reference AD).  ``has_prev`` is 0 only for the first token of a history (the empty context at test time).

DICP interleaves a query-action token ``[s_j, a_j]`` after each transition token, so the sequence is
``T_0, Q_0, T_1, Q_1, ...`` (2 tokens per transition).  The action head reads the ``T`` outputs; the
reward, next-state and return-to-go heads read the ``Q`` outputs (paper eq. "DICP").  ``Q_j`` carries
no outcome of ``a_j``, so no label leaks into its own input, and the planner (``lhf_hf.evaluation``)
can extend a cached context with ``Q`` and imagined ``T`` tokens exactly as they appear in training.
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn
from transformers import LlamaModel
from transformers.modeling_outputs import ModelOutput
from transformers.models.llama.modeling_llama import LlamaPreTrainedModel

from lhf_hf.errors import UserError

from .attention import band_mask, token_windows
from .configuration_icrl import QUERY_FEATURES, TRANSITION_FEATURES, ICRLConfig
from .train_attention import NAME as TRAIN_ATTENTION  # registers the attention function

LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0  # Gaussian head: keeps the NLL finite early in training

# The name under which ``LlamaModel.forward`` takes and returns its KV cache: ``past_key_values``
# up to transformers 5.23, ``cache`` from 5.24 on (the old name is deprecated there, and every
# ``ModelOutput.__init__`` renames a ``past_key_values`` keyword to ``cache``).  Read off the
# signature once, so the backbone is called by whichever name the installed version owns; our own
# inputs and outputs use ``backbone_cache``, a name no transformers release renames.
_LLAMA_CACHE_ARG = (
    "cache" if "cache" in inspect.signature(LlamaModel.forward).parameters else "past_key_values"
)


@dataclass
class ICRLOutput(ModelOutput):
    """Output of ``ICRLModel.forward``. ``B`` batch, ``T`` transitions, ``A`` actions, ``S`` state dim.

    loss: action loss + xi * dynamics loss (when labels were given).
    action_loss / dynamics_loss: the two parts (dynamics: DICP only).
    action_logits: (B, T, A) categorical logits (discrete actions).
    action_mean / action_log_std: (B, T, A) Gaussian policy (continuous actions).
    reward_pred: (B, T) predicted reward of (s_j, a_j) (DICP; with reward classes: the most likely
        class's value).
    reward_logits: (B, T, C) logits over ``config.reward_values`` (DICP with reward classes).
    next_state_logits: logits of s'_j (DICP, integer states): (B, T, S, bins) per coordinate, or
        (B, T, cells) with ``state_encoding="cells"``.
    next_state_pred: (B, T, S) predicted s'_j (DICP, real-valued states).
    return_pred: (B, T) predicted return-to-go from (s_j, a_j), in units of ``return_scale`` (DICP).
    backbone_cache: the backbone's KV cache (a ``transformers.Cache``) when ``use_cache``.
    """

    loss: torch.FloatTensor | None = None
    action_loss: torch.FloatTensor | None = None
    dynamics_loss: torch.FloatTensor | None = None
    action_logits: torch.FloatTensor | None = None
    action_mean: torch.FloatTensor | None = None
    action_log_std: torch.FloatTensor | None = None
    reward_pred: torch.FloatTensor | None = None
    reward_logits: torch.FloatTensor | None = None
    next_state_logits: torch.FloatTensor | None = None
    next_state_pred: torch.FloatTensor | None = None
    return_pred: torch.FloatTensor | None = None
    backbone_cache: object | None = None


def _width(layout: dict[str, slice]) -> int:
    """The width of a feature vector: the stop of its layout's last part."""
    return list(layout.values())[-1].stop


class ICRLPreTrainedModel(LlamaPreTrainedModel):
    config_class = ICRLConfig
    base_model_prefix = "icrl"
    # Trainer must not rescale our (already averaged) loss by the number of processes (docs/design.md 6).
    accepts_loss_kwargs = False


class ICRLModel(ICRLPreTrainedModel):
    """Embedders + ``LlamaModel`` + heads; ``forward`` returns an ``ICRLOutput`` with ``loss``."""

    def __init__(self, config: ICRLConfig):
        requested = config._attn_implementation  # None unless the caller chose one
        super().__init__(config)
        if requested is None:
            # SDPA, with training's attention dropout computed faster (train_attention.py)
            config._attn_implementation = TRAIN_ATTENTION
        self.backbone = LlamaModel(config)
        # Tokens enter through inputs_embeds: the vocabulary embedding is never used, and an unused
        # parameter would break DistributedDataParallel's gradient reduction.
        self.backbone.embed_tokens = None
        D = config.hidden_size
        # feature widths: the stop of the last part of each layout
        self.embed_transition = nn.Linear(_width(config.transition_layout), D)
        self.embed_dropout = nn.Dropout(config.embedding_dropout)
        A = config.action_dim
        self.action_head = nn.Linear(D, A if config.discrete_actions else 2 * A)
        if config.objective == "dicp":
            self.embed_query_action = nn.Linear(_width(config.query_layout), D)
            rv = config.reward_values
            self.reward_head = nn.Linear(D, len(rv) if rv else 1)  # classes, or a regression
            self.return_head = nn.Linear(D, 1)
            # logits per cell, per coordinate's bin, or the real-valued state: an encoded state's width
            self.next_state_head = nn.Linear(D, config.state_features)
        self.post_init()

    # ------------------------------------------------------------------ encoders
    @property
    def _dtype(self) -> torch.dtype:
        # PreTrainedModel.dtype walks every parameter; this is called for every token of a rollout
        return self.embed_transition.weight.dtype

    @property
    def state_features(self) -> int:
        """Width of an encoded state (``ICRLConfig.state_features``)."""
        return self.config.state_features

    def cell_of(self, states: torch.Tensor) -> torch.Tensor:
        """(..., S) integer coordinates -> (...) cell index, row-major (clamped to the grid)."""
        bins, S = self.config.state_bins, self.config.state_dim
        strides = bins ** torch.arange(S - 1, -1, -1, device=states.device)  # (S,)
        return (states.long().clamp(0, bins - 1) * strides).sum(-1)

    def coords_of(self, cells: torch.Tensor) -> torch.Tensor:
        """(...) cell index -> (..., S) integer coordinates; ``cell_of``'s inverse."""
        bins, S = self.config.state_bins, self.config.state_dim
        strides = bins ** torch.arange(S - 1, -1, -1, device=cells.device)  # (S,)
        return (cells[..., None] // strides) % bins

    def encode_states(self, states: torch.Tensor) -> torch.Tensor:
        """(..., S) -> (..., cells) one cell one-hot, (..., S * bins) one-hot per coordinate, or
        (..., S) float (``ICRLConfig.state_encoding``)."""
        c = self.config
        if c.cell_encoded:
            return F.one_hot(self.cell_of(states), c.cells).to(self._dtype)  # (..., cells)
        if c.state_bins:
            onehot = F.one_hot(states.long().clamp(0, c.state_bins - 1), c.state_bins)
            return onehot.flatten(-2).to(self._dtype)  # (..., S, bins) -> (..., S * bins)
        return states.to(self._dtype)

    def encode_actions(self, actions: torch.Tensor) -> torch.Tensor:
        """(...) action ids -> (..., A) one-hot, or (..., A) float actions as they are."""
        if self.config.discrete_actions:
            return F.one_hot(
                actions.long().clamp(0, self.config.action_dim - 1), self.config.action_dim
            ).to(self._dtype)
        return actions.to(self._dtype)

    # ------------------------------------------------------------------ pieces (used by planners too)
    def transition_features(
        self, states, prev_states, prev_actions, prev_rewards, prev_dones, has_prev
    ) -> torch.Tensor:
        """Transition tokens' feature vectors (B, T, F), parts in ``TRANSITION_FEATURES`` order
        (``ICRLConfig.transition_layout``)."""
        keep = has_prev.to(self._dtype).unsqueeze(-1)  # (B, T, 1): zero the missing previous step
        parts = {
            "prev_state": self.encode_states(prev_states) * keep,  # (B, T, S')
            "prev_action": self.encode_actions(prev_actions) * keep,  # (B, T, A)
            "prev_reward": prev_rewards.to(self._dtype).unsqueeze(-1) * keep,  # (B, T, 1)
            "prev_done": prev_dones.to(self._dtype).unsqueeze(-1) * keep,  # (B, T, 1)
            "has_prev": keep,  # (B, T, 1)
            "state": self.encode_states(states),  # (B, T, S')
        }
        return torch.cat([parts[name] for name in TRANSITION_FEATURES], dim=-1)  # (B, T, F)

    def embed_transitions(
        self, states, prev_states, prev_actions, prev_rewards, prev_dones, has_prev
    ) -> torch.Tensor:
        """Transition tokens (B, T, D); see the module docstring for the layout."""
        feats = self.transition_features(
            states, prev_states, prev_actions, prev_rewards, prev_dones, has_prev
        )  # (B, T, F)
        return self.embed_transition(feats)  # (B, T, D)

    def query_features(self, states, actions) -> torch.Tensor:
        """DICP query-action tokens' feature vectors (B, T, F), parts in ``QUERY_FEATURES`` order
        (``ICRLConfig.query_layout``)."""
        parts = {"state": self.encode_states(states), "action": self.encode_actions(actions)}
        return torch.cat([parts[name] for name in QUERY_FEATURES], dim=-1)  # (B, T, F)

    def embed_query_actions(self, states, actions) -> torch.Tensor:
        """DICP query-action tokens (B, T, D) from the state and the action taken in it."""
        return self.embed_query_action(self.query_features(states, actions))  # (B, T, D)

    def run_backbone(
        self,
        inputs_embeds,
        backbone_cache=None,
        position_ids=None,
        use_cache=None,
        attention_mask=None,
    ):
        """LlamaModel over token embeddings (B, L, D) -> (hidden (B, L, D), cache).

        attention_mask: None (causal) or a custom (B, 1, L, past + L) mask passed to attention as is:
        boolean (True = may attend) or additive float (the planner's tree of imagined paths over a
        shared cached context).
        backbone_cache: a ``transformers.Cache`` to extend (None: start afresh).
        """
        out = self.backbone(
            inputs_embeds=self.embed_dropout(inputs_embeds),
            attention_mask=attention_mask,
            position_ids=position_ids,
            use_cache=use_cache,
            **{_LLAMA_CACHE_ARG: backbone_cache},
        )
        return out.last_hidden_state, getattr(out, _LLAMA_CACHE_ARG)

    def action_distribution(self, hidden: torch.Tensor) -> dict[str, torch.Tensor]:
        """Policy head on transition-token outputs (B, T, D)."""
        out = self.action_head(hidden)
        if self.config.discrete_actions:
            return {"action_logits": out}  # (B, T, A)
        mean, log_std = out.chunk(2, dim=-1)  # (B, T, A) each
        return {"action_mean": mean, "action_log_std": log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)}

    def dynamics(self, hidden: torch.Tensor) -> dict[str, torch.Tensor]:
        """DICP heads on query-action outputs (B, T, D)."""
        c = self.config
        r = self.reward_head(hidden)  # (B, T, C) class logits, or (B, T, 1)
        out = {"return_pred": self.return_head(hidden).squeeze(-1)}  # (B, T)
        if c.reward_values:
            out["reward_logits"] = r
            # the imagined reward is the most likely class's value (the reference scores the
            # argmax class and feeds it back into the imagined transition)
            values = torch.tensor(c.reward_values, dtype=r.dtype, device=r.device)  # (C,)
            out["reward_pred"] = values[r.argmax(-1)]  # (B, T)
        else:
            out["reward_pred"] = r.squeeze(-1)  # (B, T)
        ns = self.next_state_head(hidden)
        if c.cell_encoded:
            out["next_state_logits"] = ns  # (B, T, cells)
        elif c.state_bins:
            out["next_state_logits"] = ns.unflatten(
                -1, (c.state_dim, c.state_bins)
            )  # (B, T, S, bins)
        else:
            out["next_state_pred"] = ns  # (B, T, S)
        return out

    def reward_class_of(self, rewards: torch.Tensor) -> torch.Tensor:
        """Class index of each reward (..., ) among ``config.reward_values``; a reward that is none
        of them raises (the data do not match the model's reward classes)."""
        # from the config, not a buffer: from_pretrained leaves non-persistent buffers uninitialised
        values = torch.tensor(self.config.reward_values, dtype=torch.float64, device=rewards.device)
        idx = (rewards.to(torch.float64)[..., None] - values).abs().argmin(-1)  # (...,)
        off = (rewards.to(torch.float64) - values[idx]).abs() > 1e-6
        if off.any():
            raise UserError(
                f"reward {float(rewards[off][0])} is not one of the model's reward values "
                f"{self.config.reward_values}"
            )
        return idx

    def predicted_next_states(self, out: dict) -> torch.Tensor:
        """Most likely next state (B, T, S) from ``dynamics`` output."""
        logits = out.get("next_state_logits")
        if logits is None:
            return out["next_state_pred"]
        if self.config.cell_encoded:
            return self.coords_of(logits.argmax(-1))  # (B, T) cell -> (B, T, S)
        return logits.argmax(-1)

    def band_attention(self, n_transitions: int, dtype=torch.float32) -> torch.Tensor:
        """(1, 1, L, L) additive mask of ``attention="band"`` over the tokens of ``n_transitions``
        transitions: every token sees its window (``modeling.attention``) and nothing older."""
        c = self.config
        win = token_windows(c.context_length, c.objective == "dicp", n_transitions)  # (L,)
        pos = torch.arange(len(win))  # (L,)
        return band_mask(pos, win, pos, dtype)[None, None]

    # ------------------------------------------------------------------ forward
    def forward(
        self,
        states: torch.Tensor,
        prev_states: torch.Tensor,
        prev_actions: torch.Tensor,
        prev_rewards: torch.Tensor,
        prev_dones: torch.Tensor,
        has_prev: torch.Tensor,
        actions: torch.Tensor | None = None,
        action_labels: torch.Tensor | None = None,
        label_mask: torch.Tensor | None = None,
        reward_labels: torch.Tensor | None = None,
        next_state_labels: torch.Tensor | None = None,
        return_labels: torch.Tensor | None = None,
        backbone_cache=None,
        position_ids: torch.Tensor | None = None,
        use_cache: bool | None = None,
    ) -> ICRLOutput:
        r"""Run a window of ``T`` transitions.

        states: (B, T, S) the state each token's action is taken from (long for integer states).
        prev_states, prev_actions, prev_rewards, prev_dones: (B, T, S), (B, T) or (B, T, A), (B, T),
            (B, T): the transition that led to ``states``; ignored where ``has_prev`` (B, T) is False.
        actions: (B, T) or (B, T, A) the action taken in ``states``: the input of DICP's query-action
            tokens (required for DICP).
        action_labels: (B, T) action ids or (B, T, A) actions to predict (AD: the source's, DPT: the
            oracle's); label_mask: (B, T) bool, the positions that carry a label (default: all).
        reward_labels (B, T), next_state_labels (B, T, S), return_labels (B, T): DICP targets
            (return-to-go in environment units; scaled by ``config.return_scale`` here).
        backbone_cache: the ``backbone_cache`` of an earlier call with ``use_cache=True``: this window
            continues that one (positions follow on unless ``position_ids`` says otherwise).

        With ``config.attention == "band"`` and more than ``context_length`` transitions (and no
        cache), every token attends to its window only (``band_attention``); else causal attention.
        """
        c = self.config
        B, T = states.shape[:2]
        tokens = self.embed_transitions(
            states, prev_states, prev_actions, prev_rewards, prev_dones, has_prev
        )  # (B, T, D)
        dicp = c.objective == "dicp"
        if dicp:
            if actions is None:
                raise UserError("DICP's forward needs `actions` (the query-action tokens' input)")
            qa = self.embed_query_actions(states, actions)  # (B, T, D)
            tokens = torch.stack([tokens, qa], dim=2).flatten(1, 2)  # (B, T, 2, D) -> (B, 2T, D)
        mask = None
        if c.attention == "band" and backbone_cache is None and T > c.context_length:
            mask = self.band_attention(T, tokens.dtype).expand(B, 1, -1, -1)  # (B, 1, L, L)
        hidden, cache = self.run_backbone(
            tokens, backbone_cache, position_ids, use_cache, attention_mask=mask
        )
        if dicp:
            hidden = hidden.unflatten(1, (T, 2))  # (B, 2T, D) -> (B, T, 2, D)
            policy_hidden, query_hidden = hidden[:, :, 0], hidden[:, :, 1]  # (B, T, D) each
        else:
            policy_hidden, query_hidden = hidden, None
        out = self.action_distribution(policy_hidden)
        if dicp:
            out.update(self.dynamics(query_hidden))

        loss = action_loss = dynamics_loss = None
        if action_labels is not None:
            mask = (
                torch.ones(B, T, dtype=torch.bool, device=states.device)
                if label_mask is None
                else label_mask.bool()
            )
            action_loss = self._action_loss(out, action_labels, mask)
            loss = action_loss
            if dicp and reward_labels is not None:
                weights = None
                if c.reward_weighting == "actions":
                    weights = self.reward_weights(actions, prev_rewards, has_prev, mask)
                dynamics_loss = self._dynamics_loss(
                    out, reward_labels, next_state_labels, return_labels, mask, weights
                )
                loss = action_loss + c.dynamics_coef * dynamics_loss
        return ICRLOutput(
            loss=loss,
            action_loss=action_loss,
            dynamics_loss=dynamics_loss,
            backbone_cache=cache if use_cache else None,
            **out,
        )

    # ------------------------------------------------------------------ losses
    def _action_loss(self, out, labels, mask) -> torch.Tensor:
        """Mean negative log-likelihood of the labelled actions."""
        if self.config.discrete_actions:
            logits = out["action_logits"][mask]  # (N, A)
            return F.cross_entropy(logits.float(), labels[mask].long())
        mean, log_std = out["action_mean"][mask], out["action_log_std"][mask]  # (N, A)
        z = (labels[mask].to(mean.dtype) - mean) * torch.exp(-log_std)
        nll = 0.5 * z.pow(2) + log_std + 0.5 * math.log(2 * math.pi)  # (N, A)
        return nll.sum(-1).mean()

    def reward_weights(self, actions, prev_rewards, has_prev, mask) -> torch.Tensor:
        """(N,) weights of the labelled positions in the reward loss (``reward_weighting="actions"``).

        Positions are grouped by the class of the previous step's reward (one more group for the
        first step of a history); within a group, a position whose action has frequency ``p`` among
        the group's positions weighs ``1 / (A p)``.  A group's weights then sum to its size times the
        fraction of the A actions it holds, so the groups keep (about) their share of the loss and
        only the actions within each are evened out.  actions, prev_rewards, has_prev: (B, T).
        """
        A = self.config.action_dim
        n_cls = len(self.config.reward_values)
        a = actions[mask].long()  # (N,)
        group = torch.where(
            has_prev[mask].bool(), self.reward_class_of(prev_rewards[mask]), n_cls
        )  # (N,) in [0, n_cls]
        key = group * A + a  # (N,) one bin per (group, action)
        counts = torch.bincount(key, minlength=(n_cls + 1) * A).view(n_cls + 1, A).float()
        p = counts / counts.sum(-1, keepdim=True).clamp(min=1)  # (n_cls + 1, A) p(a | group)
        return 1.0 / (A * p.flatten()[key])  # (N,)

    def _dynamics_loss(
        self, out, rewards, next_states, returns, mask, weights=None
    ) -> torch.Tensor:
        """Reward loss + next-state loss (cross-entropy per integer coordinate, else MSE) + return MSE.

        Squared error is the Gaussian log-likelihood of W_theta in the paper's DICP objective up to
        constants; integer grid coordinates get a categorical likelihood so the planner can imagine
        exact grid states.  weights: (N,) per labelled position for the reward loss
        (``reward_weights``; None = every position alike); the loss is their weighted mean.
        """
        c = self.config
        if c.reward_values:
            per_pos = F.cross_entropy(
                out["reward_logits"][mask].float(),
                self.reward_class_of(rewards[mask]),
                reduction="none",
            )  # (N,)
            reward_loss = (
                per_pos.mean() if weights is None else (per_pos * weights).sum() / weights.sum()
            )
        else:
            reward_loss = F.mse_loss(out["reward_pred"][mask], rewards[mask].to(self._dtype))
        return_loss = F.mse_loss(
            out["return_pred"][mask], returns[mask].to(self._dtype) / c.return_scale
        )
        if c.cell_encoded:
            logits = out["next_state_logits"][mask]  # (N, cells)
            state_loss = F.cross_entropy(logits, self.cell_of(next_states[mask]))
        elif c.state_bins:
            logits = out["next_state_logits"][mask]  # (N, S, bins)
            state_loss = F.cross_entropy(logits.flatten(0, 1), next_states[mask].long().flatten())
        else:
            state_loss = F.mse_loss(out["next_state_pred"][mask], next_states[mask].to(self._dtype))
        return reward_loss + state_loss + return_loss
