"""What a selection kept: the score distribution per task and selected-vs-rejected learning curves."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lhf_hf import constants as C
from lhf_hf.utils.io import save_figure_atomic


def plot_selection(
    selection_table,
    returns: dict[int, list[float]],
    path: str | Path,
    title: str,
    max_tasks: int = 40,
) -> None:
    """Left: U of every history of (up to ``max_tasks``) tasks, selected ones sized by their count.
    Right: mean return per episode of the selection (weighted by count) vs the rejected histories
    vs the whole source."""
    import matplotlib  # deferred: 0.5 s, paid only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: after matplotlib.use("Agg")

    t = selection_table
    task = t.column(C.TASK_ID).to_numpy()
    hist = t.column(C.HISTORY_INDEX).to_numpy()
    score = t.column("score").to_numpy()
    count = t.column("count").to_numpy()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4), dpi=110)
    tasks = np.unique(task)[:max_tasks]
    for x, tk in enumerate(tasks):
        rows = task == tk
        s, c = score[rows], count[rows]
        ax1.scatter(
            np.full((c == 0).sum(), x),
            s[c == 0],
            s=6,
            color="tab:gray",
            alpha=0.5,
            label="rejected" if x == 0 else None,
        )
        ax1.scatter(
            np.full((c > 0).sum(), x),
            s[c > 0],
            s=6 + 10 * c[c > 0],
            color="tab:green",
            alpha=0.6,
            label="selected (size = count)" if x == 0 else None,
        )
    ax1.set_xticks(range(len(tasks)))
    ax1.set_xticklabels([str(k) for k in tasks], rotation=90, fontsize=6)
    ax1.set_xlabel(
        "task"
        + (
            f" (first {max_tasks} of {np.unique(task).size})"
            if np.unique(task).size > max_tasks
            else ""
        )
    )
    ax1.set_ylabel("U = Improvement + lambda * Stability")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)

    curves = np.asarray([returns[int(h)] for h in hist], dtype=np.float64)  # (N, E)
    x = np.arange(1, curves.shape[1] + 1)
    ax2.plot(x, curves.mean(0), color="black", linestyle="--", label=f"source ({len(hist)})")
    if count.sum() > 0:
        ax2.plot(
            x,
            np.average(curves, axis=0, weights=count),
            color="tab:green",
            label=f"selection ({int((count > 0).sum())} unique, weighted by count)",
        )
    if (count == 0).any():
        ax2.plot(
            x,
            curves[count == 0].mean(0),
            color="tab:gray",
            label=f"rejected ({int((count == 0).sum())})",
        )
    ax2.set_xlabel("episode in history")
    ax2.set_ylabel("mean episode return")
    ax2.legend(fontsize=8)
    ax2.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_figure_atomic(fig, path)
