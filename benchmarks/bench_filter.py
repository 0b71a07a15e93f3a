"""LHF selection and materialisation time on a history dataset (target: full Darkroom, 8,100
histories / 8.1M frames: selection < 1 s, materialisation < 10 s).

    python benchmarks/bench_filter.py data/darkroom [--json OUT]

Baseline (same run): a plain-Python transcription of the paper's Algorithm 1: a loop over the
histories computing Improvement/Stability/U with Python lists, then per task the while/for loop
drawing one uniform per history.  It also cross-checks our scores against it.
"""

from __future__ import annotations

import argparse
import json
import random
import tempfile
import time

import numpy as np

from lhf_hf import constants as C
from lhf_hf.configs import FilterConfig
from lhf_hf.envs import get_spec
from lhf_hf.filtering import filter_histories, materialize
from lhf_hf.histories import load_histories


def reference_python(
    task_of: list[int], returns: list[list[float]], r_max: dict[int, float], lam: float, seed: int
):
    """The paper's pseudo-code, literally: per-history Python loops, linear sampling."""
    scores = []
    for t, r in zip(task_of, returns, strict=True):
        imp = (sum(r) / len(r) + (max(r) - min(r))) / (2 * r_max[t])
        drops = [b - a for a, b in zip(r[:-1], r[1:], strict=True) if b - a < 0]
        stab = 1 + (sum(drops) / len(drops)) / r_max[t] if drops else 1.0
        scores.append(imp + lam * stab)
    by_task: dict[int, list[int]] = {}
    for i, t in enumerate(task_of):
        by_task.setdefault(t, []).append(i)
    rng = random.Random(seed)
    counts = [0] * len(task_of)
    for rows in by_task.values():
        u = [scores[i] for i in rows]
        lo, hi = min(u), max(u)
        p = [(x - lo) / (hi - lo) if hi > lo else 1.0 for x in u]
        order = sorted(range(len(rows)), key=lambda k: -u[k])
        n = 0
        while n < len(rows):
            for k in order:
                if rng.random() < p[k]:
                    counts[rows[k]] += 1
                    n += 1
                    if n == len(rows):
                        break
    return np.asarray(scores), np.asarray(counts)


def best_of(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--json")
    args = p.parse_args()
    ds = load_histories(args.dataset)
    hist = ds.histories.data.table
    task_of = hist.column(C.TASK_ID).to_pylist()
    returns = hist.column(C.RETURNS).to_pylist()
    r_max = dict(enumerate(get_spec(ds.env_id).optimal_returns().tolist()))

    results = {
        "dataset": str(ds.root),
        "histories": hist.num_rows,
        "frames": ds.info["total_frames"],
    }
    ours = filter_histories(ds, FilterConfig())
    ref_scores, ref_counts = reference_python(task_of, returns, r_max, 1.0, 0)
    np.testing.assert_allclose(ours.table.column("score").to_numpy(), ref_scores, rtol=1e-12)
    results["scores_match_reference"] = True
    results["reference_python_s"] = best_of(
        lambda: reference_python(task_of, returns, r_max, 1.0, 0), args.repeats
    )
    for strategy in ("linear", "softmax"):
        results[f"selection_{strategy}_s"] = best_of(
            lambda s=strategy: filter_histories(ds, FilterConfig(strategy=s)), args.repeats
        )
    results["ratio_reference_over_linear"] = (
        results["reference_python_s"] / results["selection_linear_s"]
    )
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        materialize(ds, ours, f"{tmp}/m", progress=False)
        results["materialize_s"] = time.perf_counter() - start
    for k, v in results.items():
        print(f"{k:>30}: {v:.4f}" if isinstance(v, float) else f"{k:>30}: {v}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()
