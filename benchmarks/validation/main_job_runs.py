"""How many runs and rollouts the main job needs for a verdict that does not depend on the CPU,
from its validation records (``remake.sh main-job``: ``lhf reproduce
benchmarks/validation/main-job.yaml`` on this CPU and on emulated AVX2, each a ``results.json``).

    python benchmarks/validation/main_job_runs.py results/validation/main-job/avx*-rollouts* \
        --run-seconds 4=103 16=98 --budget 600 --out results/validation/main-job

Per record: the runs' paired return differences (LHF - baseline), their mean and 95% interval,
and the verdict the report prints (``reproduce.report.verdict``).  Per rollout count R (the
records of both CPUs at R, two draws of the same runs): the mean difference ``mu`` and the pooled
sample std ``sigma`` of one run's difference, then for n runs the chance that the report reads
"helps" (the paired t-test's 95% interval above 0: noncentral t with n - 1 degrees of freedom and
noncentrality mu / sigma * sqrt(n)) and the chance that two CPUs' independent draws both read it,
its square.  Both are plug-in estimates at the measured mu and sigma.  ``--run-seconds R=S`` is
the main job's wall time per run at --jobs 2 with R rollouts; n runs whose n x S exceeds
``--budget`` are marked.  The choice: of the (R, n) within the budget whose two draws both read
"helps" with probability >= 0.9, the fastest; if none, the one most likely to.  Writes
``runs.json`` and ``runs.md``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy import stats

from lhf_hf.reproduce.report import verdict
from lhf_hf.utils.io import write_json_atomic, write_text_atomic

AGREEMENT = 0.9  # the chance that two CPUs both read "helps" that the choice asks for
RUNS = range(3, 11)


def read(folder: Path) -> tuple[int, np.ndarray, dict]:
    """A validation record's rollouts per goal, its runs' paired differences (LHF - baseline) and
    its one AD row (``results.json`` of ``lhf reproduce`` on validation goals)."""
    path = folder / "results.json"
    try:
        data = json.loads(path.read_text())
        (cell,) = data["cells"]
        (row,) = cell["rows"]
        evaluate = data["experiment"]["evaluate"]
        rollouts = int(evaluate["rollouts"])
        d = np.array(row["lhf_run_means"], float) - np.array(row["baseline_run_means"], float)
    except OSError as err:
        raise SystemExit(f"{path}: cannot be read ({err.strerror})") from err
    except (ValueError, KeyError, TypeError) as err:
        raise SystemExit(
            f"{path}: not a main-job validation record (one cell, one row: {err})"
        ) from err
    if evaluate.get("tasks") != "validation":
        raise SystemExit(
            f"{path}: evaluated on {evaluate.get('tasks')!r} goals, not on validation goals"
        )
    return rollouts, d, row


def helps(mu: float, sigma: float, n: int) -> float:
    """The chance that the paired t-test's 95% interval lies above 0 (the report's "helps") for n
    runs whose differences have mean ``mu`` and std ``sigma``."""
    df = n - 1
    crit = stats.t.ppf(0.975, df)
    if sigma == 0:
        return 1.0 if mu > 0 else 0.0
    p = stats.nct.sf(crit, df, mu / sigma * np.sqrt(n))
    if not np.isfinite(p):  # scipy's series fails far in the tail
        p = 1.0 if mu > 0 else 0.0
    return float(p)


def seconds(pairs: list[str]) -> dict[int, float]:
    """``["4=103", "16=119"]`` -> ``{4: 103.0, 16: 119.0}``."""
    try:
        out = {int(k): float(v) for k, v in (p.split("=") for p in pairs)}
    except ValueError as err:
        raise SystemExit(f"--run-seconds takes ROLLOUTS=SECONDS pairs, not {pairs}") from err
    if not all(np.isfinite(v) and v > 0 for v in out.values()):
        raise SystemExit(f"--run-seconds: seconds must be positive, not {pairs}")
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("records", nargs="+", type=Path, help="lhf reproduce folders (results.json)")
    p.add_argument("--run-seconds", nargs="+", required=True, metavar="ROLLOUTS=SECONDS",
                   help="the main job's wall per run at --jobs 2, per rollout count")  # fmt: skip
    p.add_argument("--budget", type=float, default=600.0, help="seconds (default 600)")
    p.add_argument("--out", type=Path, required=True, help="folder for runs.json and runs.md")
    args = p.parse_args()
    per_run = seconds(args.run_seconds)
    if args.out.exists() and not args.out.is_dir():
        raise SystemExit(f"--out {args.out}: a file, not a folder")
    if len({f.resolve() for f in args.records}) != len(args.records):
        raise SystemExit("a record is named twice: each is one draw of the runs")

    records, groups = [], {}
    for folder in args.records:
        rollouts, d, row = read(folder)  # d: (runs,)
        groups.setdefault(rollouts, []).append(d)
        records.append(
            {"record": folder.name, "rollouts": rollouts, "runs": len(d),
             "differences": d.round(3).tolist(), "diff": row["diff"],
             "diff_ci95": row["diff_ci95"], "verdict": verdict(row)}
        )  # fmt: skip
    missing = sorted(set(groups) - set(per_run))
    if missing:
        raise SystemExit(f"--run-seconds names no wall time for {missing} rollouts")
    table, spread = [], {}
    for rollouts, diffs in sorted(groups.items()):
        mu = float(np.concatenate(diffs).mean())
        dof = sum(len(d) - 1 for d in diffs)
        if dof < 1:
            raise SystemExit(f"{rollouts} rollouts: no record with 2+ runs to measure a spread")
        if len(diffs) < 2:
            print(f"{rollouts} rollouts: one record, one CPU's draw: its spread is that CPU's only")
        sigma = float(np.sqrt(sum((len(d) - 1) * d.var(ddof=1) for d in diffs) / dof))
        spread[rollouts] = {"mu": mu, "sigma": sigma, "dof": dof, "records": len(diffs)}
        for n in RUNS:
            pw = helps(mu, sigma, n)
            wall = per_run[rollouts] * n
            table.append(
                {"rollouts": rollouts, "runs": n, "helps": pw, "both_help": pw**2,
                 "wall_s": wall, "fits": wall <= args.budget}
            )  # fmt: skip
    fitting = [t for t in table if t["fits"]]
    enough = sorted((t for t in fitting if t["both_help"] >= AGREEMENT), key=lambda t: t["wall_s"])
    best = max(fitting, key=lambda t: t["both_help"], default=None)
    chosen = enough[0] if enough else best
    result = {
        "records": records,
        "spread": {str(k): v for k, v in spread.items()},
        "run_seconds": {str(k): v for k, v in per_run.items()},
        "budget_s": args.budget,
        "table": table,
        "chosen": chosen and {"rollouts": chosen["rollouts"], "runs": chosen["runs"]},
    }
    lines = [
        "| record | rollouts | runs | differences per run (LHF - baseline) | mean (95% CI) | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for r in records:
        lo, hi = r["diff_ci95"]
        lines.append(
            f"| {r['record']} | {r['rollouts']} | {r['runs']} | "
            f"{', '.join(f'{x:+.2f}' for x in r['differences'])} | {r['diff']:+.2f} "
            f"({lo:+.2f} .. {hi:+.2f}) | {r['verdict']} |"
        )
    lines.append("")
    for rollouts, s in sorted(spread.items()):
        lines.append(
            f"- {rollouts} rollouts ({s['records']} records): mean difference {s['mu']:+.2f}, "
            f"pooled std of one run's difference {s['sigma']:.2f} ({s['dof']} degrees of freedom)"
        )
    lines += [
        "",
        "| rollouts | runs | reads helps | two CPUs both read helps | projected wall | within budget |",
        "|---|---|---|---|---|---|",
    ]
    for t in table:
        lines.append(
            f"| {t['rollouts']} | {t['runs']} | {t['helps']:.3f} | {t['both_help']:.3f} | "
            f"{t['wall_s'] / 60:.1f} min | {'yes' if t['fits'] else 'no'} |"
        )
    lines += ["", f"Chosen: {result['chosen']}."]
    write_json_atomic(result, args.out / "runs.json")
    write_text_atomic("\n".join(lines) + "\n", args.out / "runs.md")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
