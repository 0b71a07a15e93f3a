"""Evaluation figures: in-context learning curves (one run) and the paper-style comparison."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lhf_hf.utils.io import save_figure_atomic


def _plt():
    import matplotlib  # deferred: 0.5 s, paid only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: after matplotlib.use("Agg")

    return plt


def plot_eval_curve(
    curves: dict[str, np.ndarray], path: Path, title: str, optimal: float | None = None
) -> None:
    """curves: label -> returns (tasks, episodes); mean over tasks with a +/- std band."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=120)
    for label, r in curves.items():
        x = np.arange(1, r.shape[1] + 1)
        m, s = r.mean(0), r.std(0)
        ax.plot(x, m, label=label)
        ax.fill_between(x, m - s, m + s, alpha=0.2, linewidth=0)
    if optimal is not None:
        ax.axhline(optimal, color="black", linestyle="--", linewidth=0.8, label="optimal (mean)")
    ax.set_xlabel("test episode")
    ax.set_ylabel("return (mean over tasks)")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure_atomic(fig, path)


def plot_comparison(rows: dict[str, dict], path: Path, title: str) -> None:
    """rows: backbone -> {"baseline": (runs, E), "lhf": (runs, E)} mean curves per run.
    Like the paper's figures: one colour per backbone, baseline dashed, LHF solid, shaded std over runs."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 3.8), dpi=120)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (backbone, r) in enumerate(rows.items()):
        c = colors[i % len(colors)]
        for kind, style in (("baseline", "--"), ("lhf", "-")):
            runs = r[kind]
            x = np.arange(1, runs.shape[1] + 1)
            m, s = runs.mean(0), runs.std(0)
            label = f"{backbone}{' (LHF)' if kind == 'lhf' else ''}"
            ax.plot(x, m, linestyle=style, color=c, label=label)
            ax.fill_between(x, m - s, m + s, color=c, alpha=0.15, linewidth=0)
    ax.set_xlabel("test episode")
    ax.set_ylabel("return")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="lower right", ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure_atomic(fig, path)


def plot_sweep(panels: dict[str, dict[str, np.ndarray]], path: Path, title: str) -> None:
    """panels: backbone -> {arm label: (runs, E) per-run mean curves}, the baseline's under
    "baseline".  Like the paper's sensitivity figure (fig_sensitivity): one panel per backbone, the
    baseline dashed, one solid line per swept value, mean over runs with a std band."""
    plt = _plt()
    n = len(panels)
    fig, axes = plt.subplots(1, n, figsize=(4.8 * n, 3.8), dpi=120, squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (backbone, arms) in zip(axes[0], panels.items(), strict=True):
        values = [a for a in arms if a != "baseline"]
        for label, runs in [("baseline", arms["baseline"]), *((a, arms[a]) for a in values)]:
            base = label == "baseline"
            c = "black" if base else colors[values.index(label) % len(colors)]
            x = np.arange(1, runs.shape[1] + 1)
            m, s = runs.mean(0), runs.std(0)
            # the baseline on top: where an arm's curve is level with it, it stays visible
            ax.plot(
                x, m, linestyle="--" if base else "-", color=c, label=label, zorder=3 if base else 2
            )
            ax.fill_between(x, m - s, m + s, color=c, alpha=0.08 if base else 0.12, linewidth=0)
        ax.set_title(backbone, fontsize=10)
        ax.set_xlabel("test episode")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    axes[0][0].set_ylabel("return")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_figure_atomic(fig, path)
