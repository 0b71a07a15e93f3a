"""Sampling probabilities from scores within one task (paper eq. "linear" and "softmax").

Both map the task's U values to [0, 1] by min-max normalisation, so the best history of the task
gets P = 1 and the worst P = 0.  When all U are equal (or the task has one history) every P is 1:
the task keeps its histories unchanged (the reference code divides by zero and drops the task).
Equality is judged on the transformed values: softmax scores that differ by less than the float
resolution of exp(U / alpha) count as equal.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lhf_hf.errors import UserError


def _minmax(x: np.ndarray) -> np.ndarray:
    lo, hi = x.min(), x.max()
    if not hi > lo:  # all equal (also one history)
        return np.ones_like(x)
    return (x - lo) / (hi - lo)


def linear(scores: np.ndarray, alpha: float) -> np.ndarray:
    """P = (U - min U) / (max U - min U)."""
    del alpha
    return _minmax(scores)


def softmax(scores: np.ndarray, alpha: float) -> np.ndarray:
    """U_soft = softmax(U / alpha) over the task, then min-max normalised.

    Computed as exp((U - max U) / alpha): the shift leaves the softmax unchanged, and the
    difference is taken before dividing, so a tiny temperature cannot make inf - inf = NaN.  A
    difference that overflows to -inf gives exp = 0, which is the exact limit alpha -> 0 (the best
    history P = 1, the others 0); a huge temperature gives the limit alpha -> inf (all P = 1).
    """
    with np.errstate(over="ignore"):  # (U - max U) / alpha -> -inf is the intended limit
        z = (scores - scores.max()) / alpha  # (n,), <= 0, the best history 0
    e = np.exp(z)
    return _minmax(e / e.sum())


#: Sampling strategies by name (``strategy=``); each maps one task's U (n,) to P (n,).
SAMPLING: dict[str, Callable[[np.ndarray, float], np.ndarray]] = {
    "linear": linear,
    "softmax": softmax,
}


def sampling_probabilities(scores, strategy: str = "linear", alpha: float = 0.125) -> np.ndarray:
    """P for one task's histories from their scores U (n,)."""
    if strategy not in SAMPLING:
        raise UserError(
            f"unknown sampling strategy {strategy!r}; choose one of {', '.join(SAMPLING)}"
        )
    if not np.isfinite(alpha) or alpha <= 0:
        raise UserError(f"alpha (softmax temperature) must be > 0, got {alpha!r}")
    u = np.asarray(scores, dtype=np.float64)
    if u.ndim != 1 or u.size == 0:
        raise UserError(f"scores must be a non-empty 1-D array, got shape {u.shape}")
    if not np.all(np.isfinite(u)):
        raise UserError("scores contain NaN or infinite values")
    return SAMPLING[strategy](u, alpha)
