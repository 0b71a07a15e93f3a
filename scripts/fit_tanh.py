"""Fit the rational tanh of the C++ PPO kernel (``vtanh`` in lhf_hf/collection/kernels/ppo_update.cpp).

    python scripts/fit_tanh.py [--clamp 9] [--p 7] [--q 4]

tanh(x) ~ x P(x^2) / Q(x^2) on [0, clamp] (odd, so this covers [-clamp, clamp]; beyond it tanh
rounds to 1 in float32), with ``--p`` coefficients in P and ``--q`` in Q (Q(0) = 1).  Minimises the
relative error: linearised least squares (x P - tanh Q) / (tanh Q_prev), re-solved with the previous
Q (Loeb's iteration), then reweighted by |error|^(1/2) each round (Lawson) towards the minimax fit.
The basis is (x^2 / clamp^2)^k, so that the least-squares problem stays well conditioned; the printed
coefficients are for x^2 itself.  Prints the fit's error in float64 and a float32 evaluation's.
"""

from __future__ import annotations

import argparse

import numpy as np


def fit(clamp: float, n_p: int, n_q: int, rounds: int = 60) -> tuple[np.ndarray, np.ndarray, float]:
    """(P coefficients, Q coefficients) in powers of x^2, lowest first, and the max relative error."""
    x = (
        (1 - np.cos(np.linspace(0, np.pi, 20_001))) / 2 * clamp
    )  # Chebyshev-spaced: dense at the ends
    x = x[x > 1e-4]  # below, x P / Q = x to float precision whatever the fit
    f, s = np.tanh(x), (x / clamp) ** 2
    w, q_prev = np.ones_like(x), np.ones_like(x)
    for r in range(rounds):
        # unknowns p_0..p_{n_p-1}, q_1..q_{n_q-1}: x P(s) - f (Q(s) - 1) = f
        basis = np.concatenate(
            [
                x[:, None] * s[:, None] ** np.arange(n_p),
                -f[:, None] * s[:, None] ** np.arange(1, n_q),
            ],
            axis=1,
        )  # (points, n_p + n_q - 1)
        scale = np.sqrt(w) / (f * q_prev)
        sol = np.linalg.lstsq(basis * scale[:, None], f * scale, rcond=None)[0]
        p, q = sol[:n_p], np.concatenate([[1.0], sol[n_p:]])
        q_prev = np.polyval(q[::-1], s)
        err = x * np.polyval(p[::-1], s) / q_prev / f - 1
        if r >= 10:  # Loeb first, then Lawson's reweighting
            w = w * np.sqrt(np.abs(err))
            w /= w.sum()
    t2 = clamp**2
    return p / t2 ** np.arange(n_p), q / t2 ** np.arange(n_q), float(np.abs(err).max())


def float32_error(p: np.ndarray, q: np.ndarray, clamp: float) -> float:
    """Max relative error of the float32 Horner evaluation over a dense grid of (0, clamp + 1]."""
    x = np.linspace(0, clamp + 1, 2_000_001, dtype=np.float32)[1:]
    c = np.minimum(x, np.float32(clamp))
    t = c * c
    num, den = np.float32(0), np.float32(0)
    for a in p.astype(np.float32)[::-1]:
        num = num * t + a
    for a in q.astype(np.float32)[::-1]:
        den = den * t + a
    y = np.minimum(c * num / den, np.float32(1))
    return float(np.max(np.abs(y / np.tanh(x.astype(np.float64)) - 1)))


def main() -> None:
    a = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    a.add_argument("--clamp", type=float, default=9.0)
    a.add_argument("--p", type=int, default=7)
    a.add_argument("--q", type=int, default=4)
    args = a.parse_args()
    p, q, err = fit(args.clamp, args.p, args.q)
    print(f"fit: max relative error {err:.3g} (float64)")
    print(f"float32 Horner (no FMA): max relative error {float32_error(p, q, args.clamp):.3g}")
    print("P (powers of x^2, lowest first):", [float(np.float32(v)) for v in p])
    print("Q (powers of x^2, lowest first):", [float(np.float32(v)) for v in q])


if __name__ == "__main__":
    main()
