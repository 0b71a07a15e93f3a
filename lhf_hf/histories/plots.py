"""Plots of learning histories (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lhf_hf.utils.io import save_figure_atomic


def learning_curves(histories: dict) -> dict[str, np.ndarray]:
    """Episode returns per learner type, {learner: (n_histories, n_episodes)}, from the columns
    ``learner`` and ``returns`` of a histories table (a dict of lists)."""
    learners = list(histories["learner"])
    returns = histories["returns"]
    out = {}
    for kind in dict.fromkeys(learners):
        out[kind] = np.asarray(
            [r for r, k in zip(returns, learners, strict=True) if k == kind], dtype=np.float64
        )
    return out


def plot_learning_curve(
    curves: dict[str, np.ndarray], path: str | Path, title: str, optimal: float | None = None
) -> None:
    """Mean return per episode index (line), +/- one std (band), 10-90% quantiles (dotted)."""
    import matplotlib  # deferred: 0.5 s, paid only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: after matplotlib.use("Agg")

    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=120)
    colors = {"ppo": "tab:red", "sac": "tab:blue", "random": "tab:gray"}
    for kind, returns in curves.items():
        x = np.arange(1, returns.shape[1] + 1)
        mean, std = returns.mean(0), returns.std(0)
        c = colors.get(kind, None)
        ax.plot(x, mean, color=c, label=f"{kind} (n={returns.shape[0]})")
        ax.fill_between(x, mean - std, mean + std, color=c, alpha=0.2, linewidth=0)
        for q in (10, 90):
            ax.plot(x, np.percentile(returns, q, axis=0), color=c, linestyle=":", linewidth=0.8)
    if optimal is not None:
        ax.axhline(optimal, color="black", linestyle="--", linewidth=0.8, label="optimal (mean)")
    ax.set_xlabel("episode in history")
    ax.set_ylabel("episode return")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure_atomic(fig, path)
