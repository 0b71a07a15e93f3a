"""The model a training builds: the ``ICRLConfig`` a ``TrainConfig`` trains on an env, the check that
a model fits an env, and how the training tasks sit in their split."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from lhf_hf import constants as C
from lhf_hf.configs.train import TrainConfig
from lhf_hf.errors import UserError
from lhf_hf.modeling import ICRLConfig, icrl_config


def sequence_length(cfg: TrainConfig, config: ICRLConfig) -> int:
    """Transitions per training item: the context (``window``) or a longer sequence (``band``)."""
    if config.attention != "band":
        return config.context_length
    if cfg.sequence_length is not None and cfg.sequence_length < config.context_length:
        raise UserError(
            f"TrainConfig.sequence_length must be >= the context length {config.context_length}, "
            f"got {cfg.sequence_length}"
        )
    return cfg.sequence_length or 4 * config.context_length


def model_config_for(spec, cfg: TrainConfig, has_optimal: bool) -> ICRLConfig:
    """The ICRLConfig that ``cfg`` trains on env ``spec`` (spaces, context, planning from the env)."""
    if cfg.objective == "dpt":
        if not spec.has_optimal_action or not has_optimal:
            raise UserError(
                f"DPT needs the oracle's optimal action of every state (column {C.OPTIMAL_ACTION}); "
                f"the {spec.env_id} dataset has none (the paper runs DPT on the gridworlds only)"
            )
    state_space, action_space = spec.state_space, spec.action_space
    integer_states = np.issubdtype(state_space.dtype, np.integer)
    if cfg.state_encoding == "cells" and not integer_states:
        raise UserError(
            f"TrainConfig.state_encoding='cells' needs integer (grid) states; {spec.env_id}'s states "
            "are real-valued: use 'coordinates' (real states are used as they are)"
        )
    discrete = isinstance(action_space, gym.spaces.Discrete)
    reward_classes = list(spec.reward_values) if spec.reward_values else None
    weighting_applies = cfg.objective == "dicp" and discrete and bool(reward_classes)
    if cfg.reward_weighting == "actions" and not weighting_applies:
        raise UserError(
            "TrainConfig.reward_weighting='actions' weighs DICP's reward-classification loss, on "
            "envs with discrete actions and few reward values; "
            + (
                f"{cfg.objective} has no reward head"
                if cfg.objective != "dicp"
                else f"{spec.env_id} has real-valued rewards or actions"
            )
            + ": use 'data'"
        )
    weighting = cfg.reward_weighting or "data"  # the reference's plain loss unless asked
    return icrl_config(
        cfg.preset,
        objective=cfg.objective,
        env_id=spec.env_id,
        state_dim=int(np.prod(state_space.shape)),
        state_bins=int(state_space.high.max()) + 1 if integer_states else 0,
        state_encoding=cfg.state_encoding,
        attention=cfg.attention,
        action_dim=int(action_space.n) if discrete else int(np.prod(action_space.shape)),
        discrete_actions=discrete,
        context_length=cfg.context_length or spec.context_length,
        label_positions=cfg.label_positions or "all",
        dynamics_coef=cfg.dynamics_coef,
        return_scale=float(spec.horizon),
        plan_horizon=spec.plan_horizon,
        reward_values=reward_classes,
        reward_weighting=weighting,
    )


def check_model_env(config: ICRLConfig, spec) -> None:
    """Raise when a model's spaces do not match an env's (a discrete head on a continuous env...)."""
    discrete = isinstance(spec.action_space, gym.spaces.Discrete)
    if config.discrete_actions != discrete:
        kind = "discrete" if config.discrete_actions else "continuous"
        raise UserError(
            f"the model has a {kind} action head but {spec.env_id} has a "
            f"{'discrete' if discrete else 'continuous'} action space {spec.action_space}"
        )
    n = int(spec.action_space.n) if discrete else int(np.prod(spec.action_space.shape))
    s = int(np.prod(spec.state_space.shape))
    if config.action_dim != n or config.state_dim != s:
        raise UserError(
            f"the model expects {config.state_dim}-dim states and {config.action_dim} actions, "
            f"{spec.env_id} has {s} and {n}"
        )


def split_coverage(spec, tasks: list[int], split_seed: int) -> dict:
    """How the training tasks sit in their split: counts of train and test tasks among them."""
    train, test = spec.split(split_seed)
    test_in = sorted(set(tasks) & set(test))
    return {
        "train_tasks": len(set(tasks) & set(train)),
        "test_tasks": len(test_in),
        "of_train": len(train),
        "of_test": len(test),
        "test_tasks_trained_on": test_in,
    }


def describe_coverage(env_id: str, split_seed: int, cov: dict) -> str:
    """One line for the user: which part of the split the training data covers."""
    head = (
        f"lhf: training data: {cov['train_tasks']} of the {cov['of_train']} train tasks of "
        f"{env_id} split seed {split_seed}"
    )
    if not cov["test_tasks"]:
        return f"{head}; its {cov['of_test']} test tasks stay unseen"
    return (
        f"{head} and {cov['test_tasks']} of its {cov['of_test']} test tasks: those are seen, and "
        "`lhf evaluate` refuses them without --allow-seen (collect with --tasks train to keep "
        "the test tasks unseen)"
    )
