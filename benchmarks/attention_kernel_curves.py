"""Do the two training attentions learn alike?  Two ``bench_icrl_curve.py`` records, one per
``--attention-kernel`` (same data, settings and seeds), side by side, step by step.

    python benchmarks/attention_kernel_curves.py results/train/attention_kernel_curve/ad-kernel \
        results/train/attention_kernel_curve/ad-torch --out results/train/attention_kernel_curve

Per checkpoint step and path: the whole-curve mean return and that of the last 10 episodes, each a
mean over trained models (a model's value: its mean over evaluation seeds) +/- the sample std over
models, and the difference kernel - torch with Welch's t-test over models (the two paths draw their
dropout masks differently, so models pair by seed only in name).  Writes ``compare.json`` and
``compare.md`` (a table) and ``compare.png`` (both curves against training steps).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy import stats

from lhf_hf.utils.io import save_figure_atomic, write_json_atomic, write_text_atomic


def per_model(record: dict, key: str) -> dict[int, np.ndarray]:
    """``{step: (models,)}`` of one curve record: each trained model's mean over eval seeds."""
    (objective,) = record["objectives"].values()
    out: dict[int, list[float]] = {}
    for run in objective["runs"]:
        for pt in run["points"]:
            out.setdefault(pt["step"], []).append(float(np.mean(pt[key])))
    return {s: np.asarray(v) for s, v in sorted(out.items())}


def compare(kernel: dict, torch_: dict) -> list[dict]:
    rows = []
    for key in ("whole_curve", "last10"):
        k, t = per_model(kernel, key), per_model(torch_, key)
        for step in sorted(set(k) & set(t)):
            a, b = k[step], t[step]
            p = (
                float(stats.ttest_ind(a, b, equal_var=False).pvalue)
                if min(a.size, b.size) > 1
                else None
            )
            rows.append({"metric": key, "step": step, "models": [int(a.size), int(b.size)],
                         "kernel": [float(a.mean()), float(a.std(ddof=1))],
                         "torch": [float(b.mean()), float(b.std(ddof=1))],
                         "difference": float(a.mean() - b.mean()), "welch_p": p})  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("kernel", type=Path, help="bench_icrl_curve --out of --attention-kernel kernel")
    ap.add_argument("torch", type=Path, help="the same with --attention-kernel torch")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    kernel, torch_ = (json.loads((p / "curve.json").read_text()) for p in (args.kernel, args.torch))
    rows = compare(kernel, torch_)
    minutes = {
        name: float(np.mean([r["points"][-1]["minutes"] for r in next(iter(rec["objectives"].values()))["runs"]]))
        for name, rec in (("kernel", kernel), ("torch", torch_))
    }  # fmt: skip
    result = {"kernel": kernel["command"], "torch": torch_["command"], "machine": kernel["machine"],
              "training_minutes_mean": minutes, "rows": rows}  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(result, args.out / "compare.json")
    lines = ["| metric | step | kernel (models) | torch (models) | kernel - torch | Welch p |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        p = "-" if r["welch_p"] is None else f"{r['welch_p']:.2f}"
        lines.append(
            f"| {r['metric']} | {r['step']:,} | {r['kernel'][0]:.2f} ± {r['kernel'][1]:.2f} "
            f"({r['models'][0]}) | {r['torch'][0]:.2f} ± {r['torch'][1]:.2f} ({r['models'][1]}) | "
            f"{r['difference']:+.2f} | {p} |"
        )
    write_text_atomic("\n".join(lines) + "\n", args.out / "compare.md")

    import matplotlib  # deferred: only the plot needs it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for i, (name, rec) in enumerate((("kernel", kernel), ("torch", torch_))):
        m = per_model(rec, "whole_curve")
        steps = list(m)
        ax.errorbar(steps, [m[s].mean() for s in steps], yerr=[m[s].std(ddof=1) for s in steps],
                    color=f"C{i}", marker="o", capsize=3, label=f"{name} attention")  # fmt: skip
    ax.set_xlabel("training steps (batch 64)")
    ax.set_ylabel("whole-curve mean return (validation goals)")
    ax.set_title("AD on Darkroom: C++ kernel vs torch training attention")
    ax.legend()
    save_figure_atomic(fig, args.out / "compare.png")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
