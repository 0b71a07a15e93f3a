"""LHF scores of a learning history (paper section 4, "Improvement and Stability").

For a history with episode returns R_1..R_E in a task whose maximal return is R_max:

    Improvement = (mean(R) + (max(R) - min(R))) / (2 R_max)
    Stability   = 1 + mean({R_{e+1} - R_e : R_{e+1} - R_e < 0}) / R_max   (= 1 without any drop)
    U           = Improvement + lambda * Stability

The reference code yields NaN for Stability when no successive difference is negative (the mean
of an empty set); we define it as 1 (no degradation at all), as docs/design.md section 5 fixes.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lhf_hf.errors import UserError


def _check(returns, r_max: float, name: str = "history") -> np.ndarray:
    r = np.asarray(returns, dtype=np.float64)
    if r.ndim != 1:
        raise UserError(f"{name}: returns must be a 1-D sequence, got shape {r.shape}")
    if r.size == 0:
        raise UserError(f"{name}: empty list of episode returns")
    if not np.all(np.isfinite(r)):
        raise UserError(f"{name}: returns contain NaN or infinite values")
    _check_r_max(r_max)
    return r


def _check_r_max(r_max) -> None:
    r = np.asarray(r_max, dtype=np.float64)
    if not np.all(np.isfinite(r)) or np.any(r <= 0):
        raise UserError(f"r_max must be a positive finite return, got {r_max!r}")


def improvement(returns: Sequence[float], r_max: float) -> float:
    """(mean(R) + max(R) - min(R)) / (2 R_max)."""
    r = _check(returns, r_max)
    return float((r.mean() + (r.max() - r.min())) / (2.0 * r_max))


def stability(returns: Sequence[float], r_max: float) -> float:
    """1 + mean of the negative successive differences / R_max; 1 when there is none."""
    r = _check(returns, r_max)
    d = np.diff(r)
    drops = d[d < 0]
    return 1.0 if drops.size == 0 else float(1.0 + drops.mean() / r_max)


def unified_score(returns: Sequence[float], r_max: float, lam: float = 1.0) -> float:
    """U = Improvement + lambda * Stability."""
    _check_lam(lam)
    return improvement(returns, r_max) + lam * stability(returns, r_max)


def _check_lam(lam: float) -> None:
    if not np.isfinite(lam) or lam < 0:
        raise UserError(f"lambda must be a finite value >= 0, got {lam!r}")


def score_arrays(returns: np.ndarray, r_max: np.ndarray, lam: float = 1.0) -> dict[str, np.ndarray]:
    """Vectorised scores of N histories with E episodes each.

    returns: (N, E) episode returns; r_max: (N,) maximal return of each history's task.
    Returns {"improvement", "stability", "score"}, each (N,).
    """
    _check_lam(lam)
    r = np.asarray(returns, dtype=np.float64)  # (N, E)
    r_max = np.broadcast_to(np.asarray(r_max, dtype=np.float64), r.shape[:1])  # (N,)
    _check_r_max(r_max)
    imp = (r.mean(1) + r.max(1) - r.min(1)) / (2.0 * r_max)
    d = np.diff(r, axis=1)  # (N, E-1)
    neg = d < 0
    n_neg = neg.sum(1)
    mean_drop = np.where(n_neg > 0, np.where(neg, d, 0.0).sum(1) / np.maximum(n_neg, 1), 0.0)
    stab = 1.0 + mean_drop / r_max  # no drop -> 1
    return {"improvement": imp, "stability": stab, "score": imp + lam * stab}
