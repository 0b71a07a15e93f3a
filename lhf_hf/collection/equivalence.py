"""Do the batched and SB3 collectors make the same histories?  A statistical comparison.

Mean learning curve = return per episode index, averaged over a task's histories and over tasks.
SB3's seed-to-seed spread is measured over S root seeds; each batched run (an independent seed) must
lie inside the ``level`` prediction interval of one new draw from SB3's seed distribution at every
block of ``block`` episodes: mean +/- t_{(1+level)/2, S-1} * sd * sqrt(1 + 1/S).  (A plain
"mean +/- 3 sd" band from 4 seeds is too narrow: the sd itself is estimated from 4 values.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lhf_hf.configs.collect import CollectConfig
from lhf_hf.utils.io import save_figure_atomic

from .batched_collector import collect_chunk
from .sb3_collector import collect_task_histories


def mean_curve(histories) -> np.ndarray:
    """(E,) mean episode return per episode index over all histories of all tasks."""
    curves = [
        th.rewards.reshape(th.num_histories, -1, h).sum(-1) for th, h in histories
    ]  # (H, E) each
    return np.concatenate(curves).mean(0)


@dataclass
class Comparison:
    env_id: str
    sb3: np.ndarray  # (S, E) one mean curve per SB3 seed
    batched: np.ndarray  # (B, E) one mean curve per batched seed
    block: int
    level: float

    @property
    def k(self) -> float:
        """Half-width of the prediction interval in units of the across-seed sd."""
        from scipy.stats import t  # deferred: 0.8 s, for the equivalence check only

        S = self.sb3.shape[0]
        return float(t.ppf((1 + self.level) / 2, S - 1) * np.sqrt(1 + 1 / S))

    def blocks(self, curves: np.ndarray) -> np.ndarray:
        E = curves.shape[-1] // self.block * self.block
        return (
            curves[..., :E].reshape(*curves.shape[:-1], -1, self.block).mean(-1)
        )  # (..., E // block)

    @property
    def band(self) -> tuple[np.ndarray, np.ndarray]:
        b = self.blocks(self.sb3)
        mean, sd = b.mean(0), b.std(0, ddof=1)
        return mean - self.k * sd, mean + self.k * sd

    @property
    def inside(self) -> np.ndarray:
        """(B, blocks) whether each batched block mean lies in SB3's band."""
        lo, hi = self.band
        b = self.blocks(self.batched)
        return (b >= lo) & (b <= hi)

    def report(self) -> str:
        lo, hi = self.band
        rows = [
            f"{self.env_id}: mean return per block of {self.block} episodes "
            f"(SB3 {self.sb3.shape[0]} seeds: {self.level:.0%} prediction band = mean +/- {self.k:.2f} sd; "
            f"batched {self.batched.shape[0]} seeds)",
            f"{'block':>5} {'SB3 mean':>9} {'band lo':>8} {'band hi':>8} "
            + " ".join(f"{'batched':>8}" for _ in self.batched),
        ]
        sb3 = self.blocks(self.sb3).mean(0)
        bat = self.blocks(self.batched)
        for i in range(sb3.size):
            rows.append(
                f"{i:>5} {sb3[i]:>9.3f} {lo[i]:>8.3f} {hi[i]:>8.3f} "
                + " ".join(
                    f"{bat[j, i]:>7.3f}{'' if self.inside[j, i] else '!'}" for j in range(len(bat))
                )
            )
        return "\n".join(rows)

    def plot(self, path) -> None:
        import matplotlib  # deferred: 0.5 s, paid only when a figure is drawn

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # deferred: after matplotlib.use("Agg")

        fig, ax = plt.subplots(figsize=(6, 3.6), dpi=120)
        x = np.arange(1, self.sb3.shape[1] + 1)
        for i, c in enumerate(self.sb3):
            ax.plot(
                x,
                c,
                color="tab:blue",
                alpha=0.5,
                linewidth=0.8,
                label="SB3 (one seed each)" if i == 0 else None,
            )
        for i, c in enumerate(self.batched):
            ax.plot(x, c, color="tab:red", linewidth=1.2, label="batched" if i == 0 else None)
        lo, hi = self.band
        for i in range(lo.size):  # block i covers episodes i*block+1 .. (i+1)*block
            ax.fill_between(
                [i * self.block + 1, (i + 1) * self.block],
                lo[i],
                hi[i],
                color="tab:blue",
                alpha=0.15,
                linewidth=0,
                label=f"SB3 {self.level:.0%} prediction band (blocks)" if i == 0 else None,
            )
        ax.set_xlabel("episode in history")
        ax.set_ylabel("mean return")
        ax.set_title(f"{self.env_id}: batched vs SB3 collector", fontsize=10)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        save_figure_atomic(fig, path)


def compare(
    env_id: str,
    tasks: list[int],
    histories: int,
    steps: int,
    sb3_seeds: list[int],
    batched_seeds: list[int],
    block: int = 5,
    level: float = 0.99,
    ppo_backend: str = "auto",
) -> Comparison:
    """Collect with both collectors (paper protocol) and compare their mean learning curves."""

    def cfg(collector: str, seed: int) -> CollectConfig:
        return CollectConfig(
            env_id,
            tasks=tasks,
            histories=histories,
            steps=steps,
            seed=seed,
            collector=collector,
            workers=1,
            ppo_backend=ppo_backend,
        )

    sb3 = []
    for s in sb3_seeds:
        c = cfg("sb3", s)
        sb3.append(mean_curve([(collect_task_histories(c, t), c.horizon) for t in c.tasks]))
    batched = []
    for s in batched_seeds:
        c = cfg("batched", s)
        batched.append(mean_curve([(th, c.horizon) for th in collect_chunk(c, list(c.tasks), 0)]))
    return Comparison(env_id, np.stack(sb3), np.stack(batched), block, level)
