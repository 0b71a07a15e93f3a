"""Configuration of ``lhf evaluate`` and ``lhf compare`` (docs/design.md 7)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal, get_args

from lhf_hf.envs import SPLIT_PARTS
from lhf_hf.errors import UserError

from .types import check_types

Context = Literal["auto", "cache", "recompute", "window"]
PlanDynamics = Literal["model", "oracle"]
PlanOrder = Literal["sample", "argmax"]
PlanTies = Literal["index", "policy"]
PlanGate = Literal["always", "reward_seen"]
CONTEXTS: tuple[str, ...] = get_args(Context)
#: copies of every task in one batch: beyond this the batch (tasks x rollouts envs) is a mistake
MAX_ROLLOUTS = 1000
#: episodes per task: 100 times the paper's 100.  A rollout's stream positions (the cached context's
#: RoPE table) and the returns ``eval_results.json`` keeps (tasks x rollouts x episodes) grow with
#: every episode, so a mistyped count fails here, not after hours or out of memory.
MAX_EPISODES = 10_000


@dataclass(frozen=True)
class EvalConfig:
    """In-context evaluation of one checkpoint.  Stored in ``eval_results.json``.

    model: checkpoint folder (``lhf train`` output).
    out: output folder (``eval_results.json``, ``eval_curve.png``).
    env_id: the env to evaluate on; None = the model's.  Must match the model's spaces.
    split_seed: train/test split; None = the split of the model's training data (recorded in its
        config, also in every ``checkpoint-N``).
    tasks: ``test`` (the unseen tasks, the paper's protocol), ``validation`` (train tasks held out
        of ``--tasks fit`` data: where tuning choices are made), ``train``, ``fit``, or task
        indices "0,3,7".
    allow_seen: evaluate tasks the model was trained on (or a model that does not record its
        training tasks); without it they are refused.  Results, plot and card then say "seen tasks".
    episodes: episodes per task (paper: 100; at most 10,000), from an empty context.
    plan: DICP planning (beam search / greedy search) once the context is full.
    seed: seeds action sampling (and Meta-World resets).
    context: how the sliding context is kept (``lhf_hf.evaluation.context``): ``auto`` the model's
        own training semantics (``window`` for a model trained on windows, ``cache`` for one trained
        with ``attention="band"``), ``cache`` the sliding-window KV cache (fast; band attention),
        ``recompute`` the same function recomputed over its receptive field every step (the
        exactness and speed reference), ``window`` the reference code's protocol (only the last K
        transitions re-encoded from scratch every step, as in a training window).
    overwrite: replace the evaluation ``out`` holds (without it, an existing one is an error).
    plan_dynamics: what the planner imagines with: ``model`` (the learned reward and next-state
        heads) or ``oracle`` (the environment's true dynamics, gridworlds without a key: the
        planner's machinery with perfect dynamics, a diagnostic, not the paper's protocol).
    plan_gate: when a discrete-action task is planned for: ``always`` once the context is full
        (the reference's) or ``reward_seen``, only while its context holds a nonzero reward (the
        others act on a policy sample): before a goal is observed any predicted reward is a false
        positive of the learned head, which the search follows instead of exploring (a departure
        from the reference for under-trained heads, docs/evaluation.md).
    rollouts: how many times each task is rolled out, side by side in one batch, each copy with its
        own action draws (and Meta-World resets); curves and E average all of them.  One rollout
        per task is the paper's protocol; on Darkroom a run's return is then mostly a draw of
        which unseen goals the policy happened to find (docs/evaluation.md), so tables that
        compare planning with the policy use several.  All copies share one seeded stream (one
        draw per row and step), so a run with N rollouts does not contain the run with fewer.
    plan_order: how the beam search ranks depth-0 candidates of equal score: ``sample`` (a
        permutation drawn from the policy, the reference's: with no predicted reward anywhere the
        action is a policy sample) or ``argmax`` (the policy's order).
    plan_ties: how the beam search ranks candidates of equal score below depth 0: ``index`` (the
        reference's: beam by beam in rank order, each beam's actions by index, so with no predicted
        reward the kept beams all descend from the best first actions and a phantom reward can
        redirect few paths) or ``policy`` (each beam's actions in the policy's order at the
        imagined state, interleaved over beams, so every first action stays in the tree; a variant
        of ours, docs/evaluation.md).
    plan_reward_threshold: the beam search imagines a nonzero reward only where the reward head
        gives it at least this probability, in (0, 1) (gridworld DICP; unset, the default: the
        most likely class, the reference's): the search maximises over hundreds of imagined candidates per
        step, so the head's rare false positives become frequent ones (a variant of ours,
        docs/evaluation.md).
    """

    model: str
    out: str
    env_id: str | None = None
    split_seed: int | None = None
    tasks: str = "test"
    episodes: int = 100
    plan: bool = False
    seed: int = 0
    context: Context = "auto"
    overwrite: bool = False
    plan_dynamics: PlanDynamics = "model"
    plan_order: PlanOrder = "sample"
    plan_ties: PlanTies = "index"
    rollouts: int = 1
    plan_gate: PlanGate = "always"
    allow_seen: bool = False
    plan_reward_threshold: float | None = None

    def __post_init__(self) -> None:
        check_types(self)
        if not 1 <= self.episodes <= MAX_EPISODES:
            raise UserError(
                f"EvalConfig.episodes (--episodes) must be between 1 and {MAX_EPISODES:,} (the paper "
                "evaluates 100; the context's positions and the returns kept grow with every "
                f"episode), got {self.episodes!r}"
            )
        if not 1 <= self.rollouts <= MAX_ROLLOUTS:
            raise UserError(
                f"EvalConfig.rollouts must be between 1 and {MAX_ROLLOUTS}, got {self.rollouts!r}"
            )
        if self.context not in CONTEXTS:
            raise UserError(f"EvalConfig.context must be one of {CONTEXTS}, got {self.context!r}")
        if self.plan_order != "sample" and not self.plan:
            raise UserError("EvalConfig.plan_order is a planning setting: pass plan=True (--plan)")
        if self.plan_ties != "index" and not self.plan:
            raise UserError("EvalConfig.plan_ties is a planning setting: pass plan=True (--plan)")
        if self.plan_gate != "always" and not self.plan:
            raise UserError("EvalConfig.plan_gate is a planning setting: pass plan=True (--plan)")
        if self.plan_reward_threshold is not None:
            if not self.plan:
                raise UserError(
                    "EvalConfig.plan_reward_threshold (--plan-reward-threshold) is a planning "
                    "setting: pass plan=True (--plan)"
                )
            if self.plan_dynamics != "model":
                raise UserError(
                    "EvalConfig.plan_reward_threshold (--plan-reward-threshold) thresholds the "
                    "learned reward head; the true dynamics (--plan-dynamics oracle) have none"
                )
            if not 0 < self.plan_reward_threshold < 1:
                raise UserError(
                    "EvalConfig.plan_reward_threshold is a probability in (0, 1), got "
                    f"{self.plan_reward_threshold!r}"
                )
        if self.plan_dynamics == "oracle" and not self.plan:
            raise UserError(
                "EvalConfig.plan_dynamics='oracle' is a planning mode: pass plan=True (--plan)"
            )
        if self.seed < 0:  # numpy's seed sequences take none (its own message names no flag)
            raise UserError(f"EvalConfig.seed must be >= 0, got {self.seed!r}")
        if self.split_seed is not None and self.split_seed < 0:
            raise UserError(f"EvalConfig.split_seed must be >= 0, got {self.split_seed!r}")
        if self.tasks not in SPLIT_PARTS:
            try:
                [int(t) for t in self.tasks.split(",")]
            except ValueError:
                raise UserError(
                    "EvalConfig.tasks must be 'test', 'train', 'validation', 'fit' or "
                    f"comma-separated task indices, got {self.tasks!r}"
                ) from None

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)
