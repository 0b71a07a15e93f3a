"""Per-task resampling: Algorithm 1 of the paper and the ablation strategies.

Algorithm 1 (LHF): scan the task's histories in a fixed order, accept history l with probability
P_l, and repeat passes until the task has as many histories as before.  The result is a multiset:
``counts[l]`` is how often history l was selected (0 = filtered out); counts sum to the task's size.
"""

from __future__ import annotations

import numpy as np

from lhf_hf.errors import UserError

from .sampling import sampling_probabilities


def task_rng(seed: int, task: int) -> np.random.Generator:
    """The acceptance draws of ``task`` depend on (seed, task) only, not on the other tasks."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(task)]))


def algorithm1(
    probabilities: np.ndarray,
    order: np.ndarray,
    rng: np.random.Generator,
    target: int | None = None,
) -> np.ndarray:
    """Counts (n,) after passes over ``order`` accepting history l when v < P_l, v ~ U[0, 1).

    ``v < P`` rather than the paper's ``v <= P``: the same law for continuous v, and it guarantees
    that P = 0 is never accepted (``rng.random()`` can return exactly 0.0).  One pass draws one v
    per history; a pass stops as soon as the target is reached, like the paper's ``break``.
    """
    p = np.asarray(probabilities, dtype=np.float64)
    n = p.size
    target = n if target is None else int(target)
    if p.max() <= 0:
        raise UserError("every sampling probability is 0: Algorithm 1 would never finish")
    counts = np.zeros(n, dtype=np.int64)
    p_scan = p[order]
    total = 0
    while total < target:
        accepted = np.flatnonzero(rng.random(n) < p_scan)[
            : target - total
        ]  # positions in scan order
        np.add.at(counts, order[accepted], 1)
        total += accepted.size
    return counts


def top_fraction_counts(scores: np.ndarray, fraction: float) -> np.ndarray:
    """Keep the best ``round(fraction * n)`` (at least 1) by U, repeated to n histories in total:
    each kept history n // k times, the best n % k once more."""
    n = scores.size
    k = max(1, min(n, round(fraction * n)))
    best = np.argsort(-scores, kind="stable")[:k]
    counts = np.zeros(n, dtype=np.int64)
    counts[best] = n // k
    counts[best[: n % k]] += 1
    return counts


def resample_task(
    scores: np.ndarray,
    task: int,
    strategy: str,
    alpha: float,
    fraction: float,
    seed: int,
    scan_order: str = "descending",
) -> tuple[np.ndarray, np.ndarray]:
    """(probabilities (n,), counts (n,)) for one task's histories with scores U (n,)."""
    n = scores.size
    if strategy == "none":
        return np.ones(n), np.ones(n, dtype=np.int64)
    if strategy == "top-fraction":
        counts = top_fraction_counts(scores, fraction)
        return (counts > 0).astype(np.float64), counts
    p = sampling_probabilities(scores, strategy, alpha)
    # Reference: histories are scanned by descending U (stable, so ties keep dataset order).
    order = np.argsort(-scores, kind="stable") if scan_order == "descending" else np.arange(n)
    return p, algorithm1(p, order, task_rng(seed, task))
