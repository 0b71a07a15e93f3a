"""How many runs the main job needs for a verdict that does not depend on the CPU, from its
validation records (``remake.sh main-job``: ``lhf reproduce benchmarks/validation/main-job.yaml``
on this CPU and on emulated AVX2, each a ``results.json``).

    python benchmarks/validation/main_job_runs.py results/validation/main-job/avx*-runs* \\
        --power-from results/validation/main-job/avx*-runs5-rollouts4 \\
        --run-seconds 103 --budget 600 --out results/validation/main-job

Per record: the runs' paired return differences (LHF - baseline), their mean and 95% interval,
and the verdict the report prints (``reproduce.report.verdict``).  From the ``--power-from``
records (two CPUs' draws of the same runs): the mean difference ``mu`` and the pooled sample std
``sigma`` of one run's difference, then for n runs the paired t-test's power
(two-sided 5 %, noncentral t with n - 1 degrees of freedom and noncentrality mu / sigma * sqrt(n))
and the chance that two CPUs' independent draws read the same verdict, power^2 + (1 - power)^2
(an effect of this size read "helps" on both or on neither).  Runs whose projected wall time
(``--run-seconds`` x n, the main job's measured seconds per run at ``--jobs 2``) exceeds
``--budget`` are marked.  The choice: the fewest runs within the budget whose agreement is >= 0.9,
else the most within the budget.  Writes ``runs.json`` and ``runs.md``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy import stats

from lhf_hf.reproduce.report import verdict
from lhf_hf.utils.io import write_json_atomic, write_text_atomic

AGREEMENT = 0.9  # the chance two CPUs read the same verdict that the choice asks for
RUNS = range(3, 11)


def row_of(folder: Path) -> dict:
    """The one AD row of a validation record (``results.json``)."""
    try:
        data = json.loads((folder / "results.json").read_text())
        (cell,) = data["cells"]
        (row,) = cell["rows"]
    except (OSError, ValueError, KeyError) as err:
        raise SystemExit(f"{folder}: not a main-job validation record ({err})") from err
    return row


def power(mu: float, sigma: float, n: int) -> float:
    """The paired t-test's power (two-sided, 5 %) for n runs whose differences have mean ``mu``
    and std ``sigma``."""
    df, nc = n - 1, mu / sigma * np.sqrt(n)
    crit = stats.t.ppf(0.975, df)
    up, down = stats.nct.sf(crit, df, nc), stats.nct.cdf(-crit, df, nc)
    if not np.isfinite(up):  # scipy's series fails far in the tail: there the test always rejects
        up = 1.0 if nc > crit else 0.0
    return float(up + (down if np.isfinite(down) else 0.0))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("records", nargs="+", type=Path)
    p.add_argument("--power-from", nargs="+", type=Path, required=True)
    p.add_argument("--run-seconds", type=float, required=True)
    p.add_argument("--budget", type=float, default=600.0)
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args()

    records = []
    for folder in args.records:
        row = row_of(folder)
        d = np.array(row["lhf_run_means"]) - np.array(row["baseline_run_means"])  # (runs,)
        records.append(
            {"record": folder.name, "runs": len(d), "differences": d.round(3).tolist(),
             "diff": row["diff"], "diff_ci95": row["diff_ci95"], "verdict": verdict(row)}
        )  # fmt: skip
    diffs = [np.array(row_of(f)["lhf_run_means"]) - np.array(row_of(f)["baseline_run_means"])
             for f in args.power_from]  # fmt: skip
    mu = float(np.concatenate(diffs).mean())
    dof = sum(len(d) - 1 for d in diffs)
    sigma = float(np.sqrt(sum((len(d) - 1) * d.var(ddof=1) for d in diffs) / dof))
    table = []
    for n in RUNS:
        pw = power(mu, sigma, n)
        table.append(
            {"runs": n, "power": pw, "agreement": pw**2 + (1 - pw) ** 2,
             "wall_s": args.run_seconds * n, "fits": args.run_seconds * n <= args.budget}
        )  # fmt: skip
    fitting = [t for t in table if t["fits"]]
    enough = [t for t in fitting if t["agreement"] >= AGREEMENT]
    chosen = (enough or fitting[-1:] or [None])[0]
    result = {
        "records": records,
        "power_from": [f.name for f in args.power_from],
        "mu": mu,
        "sigma": sigma,
        "run_seconds": args.run_seconds,
        "budget_s": args.budget,
        "table": table,
        "chosen_runs": chosen and chosen["runs"],
    }
    lines = [
        "| record | runs | differences per run (LHF - baseline) | mean (95% CI) | verdict |",
        "|---|---|---|---|---|",
    ]
    for r in records:
        lo, hi = r["diff_ci95"]
        lines.append(
            f"| {r['record']} | {r['runs']} | {', '.join(f'{x:+.2f}' for x in r['differences'])}"
            f" | {r['diff']:+.2f} ({lo:+.2f} .. {hi:+.2f}) | {r['verdict']} |"
        )
    lines += [
        "",
        f"From {', '.join(result['power_from'])}: mean difference {mu:+.2f}, pooled std of one "
        f"run's difference {sigma:.2f} ({dof} degrees of freedom).",
        "",
        "| runs | power (paired t, 5 %) | two CPUs agree | projected wall | within budget |",
        "|---|---|---|---|---|",
    ]
    for t in table:
        lines.append(
            f"| {t['runs']} | {t['power']:.2f} | {t['agreement']:.2f} | {t['wall_s'] / 60:.1f} min"
            f" | {'yes' if t['fits'] else 'no'} |"
        )
    lines += ["", f"Chosen: {result['chosen_runs']} runs."]
    write_json_atomic(result, args.out / "runs.json")
    write_text_atomic("\n".join(lines) + "\n", args.out / "runs.md")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
