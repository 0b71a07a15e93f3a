"""The reference collector: Stable-Baselines3 PPO/SAC learners whose streams are the histories.

Protocols (docs/design.md section 3; ``CollectConfig.protocol``):
  paper        one learner per task over H parallel copies (``DummyVecEnv``); copy i -> history i.
  independent  H learners, each seeded on its own, each acting in one copy.
  noisy        ``paper`` on round(0.7 H) copies + a uniform random policy on the other copies
               (own copies: random transitions never feed the learner's updates).
  learners     K learners (``CollectConfig.learners``), each seeded on its own, each over H / K
               copies; learner k's copies -> histories k H / K ... (k + 1) H / K - 1.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import DummyVecEnv

from lhf_hf.configs.collect import CollectConfig
from lhf_hf.envs import get_spec, make
from lhf_hf.histories.schema import TaskHistories
from lhf_hf.histories.writer import write_task

from .recorder import RecordingVecEnv


@dataclass(frozen=True)
class LearnerPlan:
    """One source of histories within a task: ``kind`` acting in ``n_streams`` copies with ``seed``."""

    kind: str  # "ppo" | "sac" | "random"
    n_streams: int
    seed: int
    learner_index: int


def task_seeds(seed: int, task: int, n: int) -> list[int]:
    """``n`` independent 31-bit seeds for task ``task`` under root ``seed`` (order-independent)."""
    state = np.random.SeedSequence([seed, task]).generate_state(n, dtype=np.uint32)
    return [int(s) & 0x7FFFFFFF for s in state]


def plan_task(config: CollectConfig, task: int) -> list[LearnerPlan]:
    """The learners that make task ``task``'s histories, in history order."""
    H = config.histories
    n_random = config.num_random_histories
    seeds = task_seeds(config.seed, task, H + 1)
    K = config.learners_per_task  # paper and noisy: one learner over the learner streams
    plans = [LearnerPlan(config.algo, (H - n_random) // K, seeds[i], i) for i in range(K)]
    if n_random:
        plans.append(LearnerPlan("random", n_random, seeds[H], len(plans)))
    return plans


def _vec_env(config: CollectConfig, task: int, n: int, seed: int) -> RecordingVecEnv:
    def factory():
        return make(config.env_id, task, split_seed=config.split_seed)

    venv = DummyVecEnv([factory] * n)
    venv.seed(seed)
    return RecordingVecEnv(
        venv, config.steps, record_optimal=get_spec(config.env_id).has_optimal_action
    )


def _run_ppo(config: CollectConfig, rec: RecordingVecEnv, seed: int) -> None:
    p = config.ppo
    model = PPO(
        "MlpPolicy",
        rec,
        learning_rate=p.learning_rate,
        n_steps=p.n_steps,
        batch_size=p.batch_size,
        n_epochs=p.n_epochs,
        gamma=p.gamma,
        seed=seed,
        device="cpu",
        verbose=0,
    )
    model.learn(total_timesteps=config.steps * rec.num_envs)


def _run_sac(config: CollectConfig, rec: RecordingVecEnv, seed: int) -> None:
    s = config.sac
    model = SAC(
        "MlpPolicy",
        rec,
        learning_rate=s.learning_rate,
        batch_size=s.batch_size,
        gamma=s.gamma,
        learning_starts=s.learning_starts,
        buffer_size=max(config.steps * rec.num_envs, s.batch_size),
        seed=seed,
        device="cpu",
        verbose=0,
    )
    model.learn(total_timesteps=config.steps * rec.num_envs)


def _run_random(config: CollectConfig, rec: RecordingVecEnv, seed: int) -> None:
    """A uniform random policy (the noisy protocol's 30%)."""
    rng = np.random.default_rng(seed)
    space = rec.action_space
    rec.reset()
    for _ in range(config.steps):
        if space.shape == ():
            actions = rng.integers(0, space.n, rec.num_envs)
        else:
            actions = rng.uniform(space.low, space.high, (rec.num_envs, *space.shape)).astype(
                np.float32
            )
        rec.step(actions)


#: Source algorithms by name: each drives a recording env until it has ``config.steps`` per copy.
RUNNERS: dict[str, Callable[[CollectConfig, RecordingVecEnv, int], None]] = {
    "ppo": _run_ppo,
    "sac": _run_sac,
    "random": _run_random,
}


def collect_task_histories(config: CollectConfig, task: int) -> TaskHistories:
    """Run every learner of ``task`` and return its histories (H, T, ...)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # same numbers whatever the worker count (and no oversubscription)
    parts, kinds, learner_index, seeds = [], [], [], []
    try:
        with warnings.catch_warnings():
            # The paper's batch sizes do not divide every rollout size (e.g. 70 noisy-protocol
            # copies); SB3 then uses one truncated minibatch per epoch, as the reference did.
            warnings.filterwarnings("ignore", message="You have specified a mini-batch size")
            for plan in plan_task(config, task):
                set_random_seed(plan.seed)
                rec = _vec_env(config, task, plan.n_streams, plan.seed)
                RUNNERS[plan.kind](config, rec, plan.seed)
                parts.append(rec.arrays())
                rec.close()
                kinds += [plan.kind] * plan.n_streams
                learner_index += [plan.learner_index] * plan.n_streams
                seeds += [plan.seed] * plan.n_streams
    finally:
        torch.set_num_threads(threads)

    def cat(key):
        if parts[0][key] is None:
            return None
        return np.concatenate([p[key] for p in parts], axis=0)

    return TaskHistories(
        task=task,
        obs=cat("obs"),
        actions=cat("actions"),
        rewards=cat("rewards"),
        next_obs=cat("next_obs"),
        dones=cat("dones"),
        optimal_actions=cat("optimal_actions"),
        success=cat("success"),
        learner=kinds,
        learner_index=np.asarray(learner_index),
        seeds=np.asarray(seeds),
    )


def collect_and_write_task(
    config_dict: dict, task: int, position: int, root: str
) -> tuple[int, int, float]:
    """Worker entry point: collect one task and commit it; returns (task, frames, seconds)."""
    start = time.perf_counter()
    config = CollectConfig.from_dict(config_dict)
    th = collect_task_histories(config, task)
    write_task(Path(root), position, th, config.horizon)
    return task, th.num_histories * th.steps, time.perf_counter() - start
