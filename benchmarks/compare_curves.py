"""Learning curves side by side: ``bench_icrl_curve.py`` records of one setting each (the same data,
seeds and evaluation), step by step, each against the first.

    python benchmarks/compare_curves.py REFERENCE OTHER [OTHER ...] --labels NAME NAME ... \
        --title TITLE --out FOLDER

    python benchmarks/compare_curves.py results/train/attention_kernel_curve/ad-kernel \
        results/train/attention_kernel_curve/ad-torch --labels kernel torch \
        --title "AD on Darkroom: C++ kernel vs torch training attention" \
        --out results/train/attention_kernel_curve

Per checkpoint step and record: the whole-curve mean return and that of the last 10 episodes, each a
mean over trained models (a model's value: its mean over evaluation seeds) +/- the sample std over
models, and the difference to the first record with Welch's t-test over models (settings that
change the training draw different dropout masks and windows, so models pair by seed only in
name).  Writes ``compare.json``, ``compare.md`` (a table) and ``compare.png`` (every curve against
training steps).
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


def compare(records: dict[str, dict]) -> list[dict]:
    """Rows per metric, step and record (the first record's rows have no difference)."""
    (ref, first), rows = next(iter(records.items())), []
    for key in ("whole_curve", "last10"):
        base = per_model(first, key)
        for name, rec in records.items():
            m = per_model(rec, key)
            for step in sorted(set(base) & set(m)):
                a, b = m[step], base[step]
                other = name != ref and min(a.size, b.size) > 1
                p = float(stats.ttest_ind(a, b, equal_var=False).pvalue) if other else None
                rows.append({"metric": key, "step": step, "record": name, "models": int(a.size),
                             "mean": float(a.mean()), "std": float(a.std(ddof=1)),
                             "difference": None if name == ref else float(a.mean() - b.mean()),
                             "welch_p": p})  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("records", type=Path, nargs="+", help="bench_icrl_curve.py --out folders")
    ap.add_argument("--labels", nargs="+", required=True, help="a name per record")
    ap.add_argument("--title", required=True)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    if len(args.records) < 2 or len(args.labels) != len(args.records):
        raise SystemExit("give 2 or more records and one --labels name per record")
    records = {
        name: json.loads((p / "curve.json").read_text())
        for name, p in zip(args.labels, args.records, strict=True)
    }
    rows = compare(records)
    minutes = {
        name: float(np.mean([r["points"][-1]["minutes"] for r in next(iter(rec["objectives"].values()))["runs"]]))
        for name, rec in records.items()
    }  # fmt: skip
    ref = args.labels[0]
    result = {"commands": {n: r["command"] for n, r in records.items()},
              "machine": records[ref]["machine"], "training_minutes_mean": minutes,
              "reference": ref, "rows": rows}  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(result, args.out / "compare.json")
    lines = [f"| metric | step | record (models) | mean ± std over models | - {ref} | Welch p |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        diff = "-" if r["difference"] is None else f"{r['difference']:+.2f}"
        p = "-" if r["welch_p"] is None else f"{r['welch_p']:.2f}"
        lines.append(
            f"| {r['metric']} | {r['step']:,} | {r['record']} ({r['models']}) | "
            f"{r['mean']:.2f} ± {r['std']:.2f} | {diff} | {p} |"
        )
    write_text_atomic("\n".join(lines) + "\n", args.out / "compare.md")

    import matplotlib  # deferred: only the plot needs it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for i, (name, rec) in enumerate(records.items()):
        m = per_model(rec, "whole_curve")
        steps = list(m)
        ax.errorbar(steps, [m[s].mean() for s in steps], yerr=[m[s].std(ddof=1) for s in steps],
                    color=f"C{i}", marker="o", capsize=3, label=name)  # fmt: skip
    ax.set_xlabel("training steps (batch 64)")
    ax.set_ylabel("whole-curve mean return (validation goals)")
    ax.set_title(args.title)
    ax.legend()
    save_figure_atomic(fig, args.out / "compare.png")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
