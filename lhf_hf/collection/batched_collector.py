"""The batched collector: every PPO learner of a chunk of gridworld tasks trained at once.

Same protocols as the SB3 collector (``paper``, ``independent``, ``noisy``, ``learners``), same PPO (see
``batched_ppo``), same observation encoding (the (row, col) state as float, what SB3's MlpPolicy
sees), same recorder semantics (true final state, oracle action before the step), same writer.
All environments of a chunk are stepped by one ``BatchedGridworld``.

Randomness is drawn per chunk (chunk c = task positions [c K, (c + 1) K)), from
``SeedSequence([seed, c, K])``: a chunk's data depends on (seed, chunk, K) only, so a resumed run
redoes unfinished chunks exactly.  Unlike the SB3 collector, a task's data therefore depends on
which chunk it is in (``tasks_per_chunk`` is part of the config).
"""

from __future__ import annotations

import logging

import numpy as np
import torch
from tqdm.auto import tqdm

from lhf_hf.configs.collect import CollectConfig
from lhf_hf.envs import get_spec, make_batched
from lhf_hf.errors import UserRuntimeError
from lhf_hf.histories.schema import TaskHistories

from . import backend_verdict, native
from .batched_ppo import HIDDEN, Rollout, StackedPolicy, gae, make_optimizer
from .ppo_backends import ppo_update

logger = logging.getLogger(__name__)


def check_device(name: str) -> torch.device:
    device = torch.device(name)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise UserRuntimeError(
            f"CollectConfig.device={name!r}, but torch sees no CUDA device here "
            f"(torch {torch.__version__}); collect with device='cpu'"
        )
    return device


def resolve_ppo_backend(config: CollectConfig) -> str:
    """``config.ppo_backend`` with ``auto`` decided (logged): on the CPU, the backend this machine
    runs faster (``backend_verdict``: measured once, cached), ``torch`` where the kernel does not
    build.  ``kernel`` that cannot build raises ``KernelUnavailable`` here."""
    if config.ppo_backend == "torch" or config.device != "cpu":
        return "torch"
    try:
        native.load(HIDDEN[0])
        if config.ppo_backend == "kernel":
            return "kernel"
        spec = get_spec(config.env_id)
        v = backend_verdict.verdict(spec.state_space.shape[0], spec.action_space.n)
    except native.KernelUnavailable as e:
        if config.ppo_backend == "kernel":
            raise
        logger.warning("batched collector: PPO updates with torch ops (%s)", e)
        return "torch"
    logger.info(
        "batched collector: PPO with %s: %.2f ms (kernel) vs %.2f ms (torch) per minibatch step "
        "on %s (%s, %d threads; %s %s)",
        "the C++ kernel" if v["choice"] == "kernel" else "torch ops",
        v["kernel_ms"],
        v["torch_ms"],
        v["cpu"],
        v["isa"],
        v["threads"],
        "cached in" if v["cached"] else "measured now, cached in",
        v["path"],
    )
    return v["choice"]


def chunk_seed(seed: int, chunk: int, size: int) -> int:
    return int(np.random.SeedSequence([seed, chunk, size]).generate_state(1)[0]) & 0x7FFFFFFF


def collect_chunk(
    config: CollectConfig, tasks: list[int], chunk: int, progress: bool = False
) -> list[TaskHistories]:
    """Collect every task of one chunk; returns one ``TaskHistories`` per task, in order."""
    spec = get_spec(config.env_id)
    H, steps, p = config.histories, config.steps, config.ppo
    n_random = config.num_random_histories
    per_task = config.learners_per_task  # learners x E streams each (noisy: random ones aside)
    E = (H - n_random) // per_task
    seed = chunk_seed(config.seed, chunk, config.tasks_per_chunk)
    device = check_device(config.device)
    gen = torch.Generator().manual_seed(seed)
    np_rng = np.random.default_rng(seed)
    learner_tasks = np.repeat(np.asarray(tasks, dtype=np.int64), per_task)  # (L,)
    L = learner_tasks.size
    core = make_batched(config.env_id, np.repeat(learner_tasks, E))  # L * E copies, learner-major
    obs_dim = spec.state_space.shape[0]
    # initialised on the CPU from the chunk's seed whatever the device: the same initial learners
    policy = StackedPolicy(L, obs_dim, spec.action_space.n, gen).to(device)
    if device.type != "cpu":  # sampling and permutations on a GPU draw from its own generator
        gen = torch.Generator(device).manual_seed(seed)
    opt = make_optimizer(policy, p.learning_rate)
    backend = resolve_ppo_backend(config)  # `auto` decided here too: callers may pass it unresolved
    gradients = {"kernel": "kernel", "torch": "manual"}[backend]
    if backend == "kernel":  # acting too: actor + critic per learner in cache

        def act(o: torch.Tensor):
            u = torch.rand(o.shape[:2], generator=gen)  # (L, E): inverse-CDF sampling
            return native.ppo_act(policy.stacked_params(), o, u)

        def value(o: torch.Tensor) -> torch.Tensor:
            return native.ppo_act(policy.stacked_params(), o, None)[2]
    else:

        def act(o: torch.Tensor):
            return policy.act(o, gen)

        value = policy.value

    # Recording: (L, E, steps) — small ints while collecting, int64 in the dataset.
    # time-major, so that each step's writes are contiguous (learner-major strided writes took ~5 ms
    # of each Key-to-Door step of 24,300 copies); transposed per task at the end
    rec_obs = np.zeros((steps, L, E, obs_dim), dtype=np.int16)
    rec_next = np.zeros_like(rec_obs)
    rec_act = np.zeros((steps, L, E), dtype=np.int8)
    rec_opt = np.zeros_like(rec_act)
    rec_rew = np.zeros((steps, L, E), dtype=np.float32)
    rec_done = np.zeros((steps, L, E), dtype=bool)

    # PPO's rollout buffer, time-major too (T, L, E, ...): contiguous per-step writes, and GAE's
    # backward pass reads contiguous time slices; viewed as (L, E, T, ...) for GAE and the update
    T = p.n_steps
    kw = {"device": device}
    buf_obs = torch.zeros(T, L, E, obs_dim, **kw)
    buf_act = torch.zeros(T, L, E, dtype=torch.int64, **kw)
    buf_logp, buf_val = torch.zeros(T, L, E, **kw), torch.zeros(T, L, E, **kw)
    buf_rew = torch.zeros(T, L, E, **kw)
    buf_start = torch.zeros(T, L, E, dtype=torch.bool, **kw)
    lem = lambda x: x.movedim(0, 2)  # noqa: E731 - (T, L, E, ...) -> (L, E, T, ...) view

    def to_device(x: np.ndarray, dtype=None) -> torch.Tensor:
        t = torch.from_numpy(x if dtype is None else x.astype(dtype))
        return t.to(device)

    obs = core.reset()  # (L*E, S)
    episode_start = torch.ones(L, E, dtype=torch.bool, **kw)
    bar = tqdm(
        total=steps,
        desc=f"chunk {chunk} ({len(tasks)} tasks, {L * E} copies)",
        unit="step",
        leave=False,
        disable=not progress,
        mininterval=1.0,
    )
    with torch.no_grad():
        for t in range(steps):
            bar.update(1)
            k = t % T
            obs_t = to_device(obs.reshape(L, E, obs_dim), np.float32)  # (L, E, d)
            rec_opt[t] = core.optimal_action().reshape(L, E)
            actions, logp, values = act(obs_t)  # (L, E) each
            actions_np = actions.cpu().numpy()  # (L, E)
            next_obs, reward, done = core.step(actions_np.reshape(-1))
            rec_obs[t] = obs.reshape(L, E, obs_dim)
            rec_act[t] = actions_np
            rec_rew[t] = reward.reshape(L, E)
            rec_next[t] = next_obs.reshape(L, E, obs_dim)
            rec_done[t] = done.reshape(L, E)
            r = to_device(reward.reshape(L, E))
            done_t = to_device(done.reshape(L, E))
            if done.any():
                # SB3: on a time-limit truncation, add gamma * V(true final state) to the reward.
                final_v = value(to_device(next_obs.reshape(L, E, obs_dim), np.float32))
                r = r + p.gamma * final_v * done_t
                obs = core.reset(done)
            else:
                obs = next_obs
            buf_obs[k], buf_act[k], buf_logp[k] = obs_t, actions, logp
            buf_val[k], buf_rew[k], buf_start[k] = values, r, episode_start
            episode_start = done_t
            if k == T - 1 and t < steps - 1:  # the last rollout's update cannot change the data
                last_v = value(to_device(obs.reshape(L, E, obs_dim), np.float32))
                adv, ret = gae(lem(buf_rew), lem(buf_val), lem(buf_start), last_v, done_t, p.gamma)
                flat = lambda x: x.reshape(L, E * T, *x.shape[3:])  # noqa: E731 - (L, E, T, ...) -> (L, E*T, ...) env-major like SB3 (copies the time-major views)
                with torch.enable_grad():
                    ppo_update(
                        policy,
                        opt,
                        Rollout(
                            flat(lem(buf_obs)),
                            flat(lem(buf_act)),
                            flat(lem(buf_logp)),
                            flat(lem(buf_val)),
                            flat(adv),
                            flat(ret),
                        ),
                        p.n_epochs,
                        p.batch_size,
                        generator=gen,
                        gradients=gradients,
                    )

    bar.close()
    random_parts = _random_streams(config, tasks, n_random, np_rng) if n_random else None
    out = []
    for i, task in enumerate(tasks):
        sl = slice(i * per_task, (i + 1) * per_task)

        def hist(rec: np.ndarray, dtype=None, sl: slice = sl) -> np.ndarray:
            # (steps, per_task, E, ...) -> (per_task * E, steps, ...)
            x = np.moveaxis(rec[:, sl], 0, 2).reshape(per_task * E, steps, *rec.shape[3:])
            return x.astype(dtype) if dtype is not None else np.ascontiguousarray(x)

        part = {
            "obs": hist(rec_obs, np.int64),
            "actions": hist(rec_act, np.int64),
            "rewards": hist(rec_rew),
            "next_obs": hist(rec_next, np.int64),
            "dones": hist(rec_done),
            "optimal_actions": hist(rec_opt, np.int64),
        }
        learner = ["ppo"] * (per_task * E)
        learner_index = np.repeat(np.arange(per_task), E)
        if random_parts is not None:
            rp = {k: v[i] for k, v in random_parts.items()}
            part = {k: np.concatenate([part[k], rp[k]]) for k in part}
            learner += ["random"] * n_random
            learner_index = np.concatenate([learner_index, np.full(n_random, per_task)])
        out.append(
            TaskHistories(
                task=task,
                success=None,
                learner=learner,
                learner_index=learner_index,
                seeds=np.full(H, seed),
                **part,
            )
        )
    return out


def _random_streams(
    config: CollectConfig, tasks: list[int], n: int, rng: np.random.Generator
) -> dict:
    """The noisy protocol's uniform random histories: (tasks, n, steps, ...) arrays."""
    spec = get_spec(config.env_id)
    core = make_batched(config.env_id, np.repeat(np.asarray(tasks), n))
    B, steps, S = core.num_envs, config.steps, spec.state_space.shape[0]
    arrays = {
        "obs": np.zeros((B, steps, S), np.int64),
        "actions": np.zeros((B, steps), np.int64),
        "rewards": np.zeros((B, steps), np.float32),
        "next_obs": np.zeros((B, steps, S), np.int64),
        "dones": np.zeros((B, steps), bool),
        "optimal_actions": np.zeros((B, steps), np.int64),
    }
    obs = core.reset()
    for t in range(steps):
        arrays["optimal_actions"][:, t] = core.optimal_action()
        a = rng.integers(0, spec.action_space.n, B)
        nxt, r, d = core.step(a)
        arrays["obs"][:, t], arrays["actions"][:, t], arrays["rewards"][:, t] = obs, a, r
        arrays["next_obs"][:, t], arrays["dones"][:, t] = nxt, d
        obs = core.reset(d) if d.any() else nxt
    return {k: v.reshape(len(tasks), n, *v.shape[1:]) for k, v in arrays.items()}
