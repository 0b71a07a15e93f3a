"""``ppo_backend="auto"``: the faster PPO backend of this machine, measured once and cached.

The C++ kernel is 3x the torch ops' speed on an AVX-512 Intel CPU and half their speed on a 2-core
AMD EPYC with AVX2 (BENCHMARKS.md), so being available is not a reason to use it.  At the first
``auto`` collection on a machine both paths run the same small stacked update (81 learners, the
size of a Darkroom chunk's minibatch steps) and the faster one is chosen; the verdict is cached
beside the kernel, keyed by the kernel library (whose key holds the compiler's expansion of
``-march=native``, i.e. the CPU's features), the CPU model and torch's version.
The two backends draw their random numbers differently, so the chosen one is part of a dataset's
identity (``CollectConfig.ppo_backend`` is stored resolved) and the verdict goes into its
provenance.  Hence one verdict per machine, measured on one thread whatever the measuring process
has: ``lhf reproduce --jobs 2`` resolves ``auto`` in its own process (two threads) and again in
each stage's child (one), and a verdict per thread count could name two backends, i.e. two stage
hashes for one collection, and the children would not find their stage.
"""

from __future__ import annotations

import copy
import hashlib
import json
import logging
import platform
import statistics
import time
from pathlib import Path

import torch

from lhf_hf.utils.io import read_json, write_json_atomic

from . import native
from .batched_ppo import HIDDEN, Rollout, StackedPolicy, make_optimizer
from .ppo_backends import ppo_update

logger = logging.getLogger(__name__)

VERDICT_VERSION = 2  # 2: one thread, not keyed by the process's thread count
#: The measured update: Darkroom's chunk size, one epoch of 8 minibatches of 50.
LEARNERS, SAMPLES, BATCH, REPEATS = 81, 400, 50, 3


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def instruction_set() -> str:
    """The widest vector extension the kernel can use here: ``avx512``, ``avx2`` or ``other``."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return "other"
    flags = next(
        (ln.split(":", 1)[1].split() for ln in text.splitlines() if ln.startswith("flags")), []
    )
    return "avx512" if "avx512f" in flags else "avx2" if "avx2" in flags else "other"


def machine(kernel: bool = True) -> dict:
    """The CPU, its widest vector extension, torch's threads and, when the kernel runs
    (``kernel``), its ``-march`` (``native`` unless another instruction set's path was asked for,
    ``native.target_march``)."""
    return {
        "cpu": cpu_model(),
        "isa": instruction_set(),
        **({"kernel_march": native.target_march()} if kernel else {}),
        "threads": torch.get_num_threads(),
    }


def _verdict_path(obs_dim: int, num_actions: int) -> Path:
    lib = native.build(HIDDEN[0])  # KernelUnavailable when it cannot be built
    key = hashlib.sha256(
        json.dumps(
            [
                VERDICT_VERSION,
                lib.name,
                cpu_model(),
                torch.__version__,
                obs_dim,
                num_actions,
            ]  # fmt: skip
        ).encode()
    ).hexdigest()[:16]
    return lib.parent / f"verdict-{key}.json"


def _rollout(obs_dim: int, num_actions: int, gen: torch.Generator) -> Rollout:
    L, N = LEARNERS, SAMPLES
    return Rollout(
        obs=torch.rand(L, N, obs_dim, generator=gen) * 8,
        actions=torch.randint(0, num_actions, (L, N), generator=gen),
        old_logp=torch.full((L, N), -1.6),
        old_values=torch.randn(L, N, generator=gen),
        advantages=torch.randn(L, N, generator=gen),
        returns=torch.randn(L, N, generator=gen),
    )


def measure(obs_dim: int, num_actions: int) -> dict:
    """Milliseconds per minibatch step of each backend on one stacked update (median of 3), on one
    thread (the module docstring says why)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _measure(obs_dim, num_actions)
    finally:
        torch.set_num_threads(threads)


def _measure(obs_dim: int, num_actions: int) -> dict:
    gen = torch.Generator().manual_seed(0)
    policy = StackedPolicy(LEARNERS, obs_dim, num_actions, gen)
    data = _rollout(obs_dim, num_actions, gen)
    steps = SAMPLES // BATCH
    out = {}
    for backend, gradients in (("kernel", "kernel"), ("torch", "manual")):
        times = []
        for repeat in range(REPEATS + 1):  # the first is a warm-up
            p = copy.deepcopy(policy)
            opt = make_optimizer(p, 3e-4)
            start = time.perf_counter()
            ppo_update(p, opt, data, 1, BATCH, generator=gen, gradients=gradients)
            if repeat:
                times.append((time.perf_counter() - start) * 1e3 / steps)
        out[f"{backend}_ms"] = round(statistics.median(times), 3)
    return out


def verdict(obs_dim: int = 2, num_actions: int = 5) -> dict:
    """The cached verdict for these sizes (measured now when there is none):
    ``{choice, kernel_ms, torch_ms, cpu, isa, threads, torch, cached, path}``.  Raises
    ``native.KernelUnavailable`` when the kernel cannot be built (then there is no choice)."""
    obs_dim, num_actions = int(obs_dim), int(num_actions)  # gym sizes may be numpy ints
    path = _verdict_path(obs_dim, num_actions)
    try:
        found = read_json(path)
        if found.get("choice") in ("kernel", "torch"):
            _last[:] = [{**found, "cached": True, "path": str(path)}]
            return _last[0]
    except (OSError, ValueError):
        pass
    times = measure(obs_dim, num_actions)
    result = {
        "choice": "kernel" if times["kernel_ms"] <= times["torch_ms"] else "torch",
        **times,
        **machine(),
        "threads": 1,  # measured on one
        "torch": torch.__version__,
        "measured": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    write_json_atomic(result, path)
    _last[:] = [{**result, "cached": False, "path": str(path)}]
    return _last[0]


def last_verdict() -> dict | None:
    """The verdict this process used last (for a dataset's provenance), or None."""
    return _last[0] if _last else None


_last: list[dict] = []
