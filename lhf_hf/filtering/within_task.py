"""Kept vs rejected histories compared within each task, not pooled over tasks.

Pooled over tasks, "kept histories return less than rejected ones" can hold while the opposite holds
in every task (Simpson's paradox): Stability keeps nearly all the flat, all-zero histories of a task
where the learner never found the goal, and such tasks weigh in with many kept low returns. The
selection summary therefore reports the comparison task by task: the mean over tasks of (kept mean
return - rejected mean return), how many tasks go each way, and a two-sided sign test over them.
"""

from __future__ import annotations

import math

import numpy as np


def sign_test(wins: int, losses: int) -> float:
    """Two-sided exact binomial p-value of ``wins`` vs ``losses`` under p = 1/2 (ties left out)."""
    n = wins + losses
    if n == 0:
        return 1.0
    k = min(wins, losses)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2**n
    return min(1.0, 2 * tail)


def within_task(task: np.ndarray, mean_return: np.ndarray, count: np.ndarray) -> dict:
    """Per-task comparison of one selection.

    task, mean_return, count: (N,) per history: its task, its mean episode return, and how many
    times the selection draws it (0 = rejected).
    """
    diffs, gains, spreads, never = [], [], [], []
    for t in np.unique(task):
        rows = task == t
        r, c = mean_return[rows], count[rows]
        gains.append(np.average(r, weights=c) - r.mean())  # what resampling does to the task
        spreads.append(r.std(ddof=1) if r.size > 1 else 0.0)
        if (c > 0).any() and (c == 0).any():
            diffs.append(r[c > 0].mean() - r[c == 0].mean())
            # no history of the task ever returned a reward: the learner never found the goal
            # (gridworld returns are >= 0), so kept and rejected tie whatever LHF chose
            never.append(bool(np.all(r == 0)))
    d, reached = np.asarray(diffs), ~np.asarray(never, dtype=bool)
    wins, losses = int((d > 0).sum()), int((d < 0).sum())
    return {
        "tasks": int(len(gains)),
        "tasks_compared": int(d.size),  # tasks with both kept and rejected histories
        "kept_minus_rejected": float(d.mean()) if d.size else None,
        "tasks_kept_higher": wins,
        "tasks_kept_lower": losses,
        "tasks_tied": int(d.size - wins - losses),
        "sign_test_p": sign_test(wins, losses),
        "selection_minus_source": float(np.mean(gains)),  # count-weighted, per task, then averaged
        "tasks_never_reached": int((~reached).sum()),  # compared tasks whose histories all return 0
        "kept_minus_rejected_reached": float(d[reached].mean()) if reached.any() else None,
        # diversity: the spread (sample std) of history mean returns within a task, averaged
        "history_spread": float(np.mean(spreads)),
    }


def describe(w: dict | None, long: bool = False) -> str:
    """``within_task``'s result as a card or report cell: the difference and the tasks each way
    (``long``: in words, with the sign test), ``-`` where no task had both kinds."""
    if not w or w.get("kept_minus_rejected") is None:
        return "-"
    d, up, down, n = (w[k] for k in ("kept_minus_rejected", "tasks_kept_higher",
                                     "tasks_kept_lower", "tasks_compared"))  # fmt: skip
    if not long:
        return f"{d:+.2f} ({up} / {down} of {n})"
    text = (
        f"{d:+.3f}: kept return more in {up}, less in {down} of {n} tasks (sign test p = "
        f"{w['sign_test_p']:.3g})"
    )
    if w.get("tasks_never_reached"):
        reached = w["kept_minus_rejected_reached"]
        text += f"; {w['tasks_never_reached']} of them never reached the goal (all returns 0), " + (
            "the others " + f"{reached:+.3f}" if reached is not None else "no other"
        )
    if w.get("history_spread") is not None:
        text += f"; spread of history returns within a task {w['history_spread']:.2f}"
    return text
