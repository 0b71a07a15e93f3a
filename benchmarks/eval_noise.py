"""How many rollouts per goal an evaluation needs: the noise of one rollout against the spread
between trained models, on validation goals, from ``bench_icrl_curve.py`` records.

    python benchmarks/eval_noise.py results/train/attention_kernel_curve/ad-kernel \
        results/train/attention_kernel_curve/ad-torch --out results/validation/rollouts

A record's evaluation seeds are independent rollouts of every goal by the same model (what
``EvalConfig.rollouts`` runs in one batch).  Per record and checkpoint step, on the whole-curve
return over all goals:

- ``rollout_std``: the std over one model's seeds (ddof 1), pooled over its models as the root
  of the mean variance: how far one rollout of all goals lands from that model's true return;
- ``model_std``: the std over models of their means over seeds, with the rollout noise of that
  mean (``rollout_std^2 / seeds``) taken out (floored at 0): how far trained models differ;
- ``std_of_R``: the std of one model's evaluated return with R rollouts,
  ``sqrt(model_std^2 + rollout_std^2 / R)``, for R = 1, 2, 4, 8.

A table compares two arms through the difference of such returns, so evaluation noise adds to the
training noise in every run; R is worth raising while ``rollout_std^2 / R`` is not small beside
``model_std^2``.  Writes ``rollouts.json`` and ``rollouts.md``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from lhf_hf.utils.io import write_json_atomic, write_text_atomic

ROLLOUTS = (1, 2, 4, 8)


def noise(record: dict) -> list[dict]:
    """Per objective and checkpoint step of one curve record: rollout and model noise."""
    rows = []
    for objective, found in record["objectives"].items():
        steps: dict[int, list[np.ndarray]] = {}
        for run in found["runs"]:
            for pt in run["points"]:
                steps.setdefault(pt["step"], []).append(np.asarray(pt["whole_curve"], float))
        for step, models in sorted(steps.items()):
            seeds = min(m.size for m in models)
            if seeds < 2:
                raise SystemExit(f"step {step}: one evaluation seed per model: no rollout noise")
            rollout_var = float(np.mean([m.var(ddof=1) for m in models]))
            means = np.asarray([m.mean() for m in models])
            between = float(means.var(ddof=1)) if means.size > 1 else float("nan")
            model_var = max(between - rollout_var / seeds, 0.0)
            rows.append({
                "objective": objective, "step": step, "models": len(models), "seeds": seeds,
                "mean_return": float(means.mean()), "rollout_std": rollout_var**0.5,
                "model_std": model_var**0.5,
                "std_of_R": {r: (model_var + rollout_var / r) ** 0.5 for r in ROLLOUTS},
            })  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("records", type=Path, nargs="+", help="bench_icrl_curve.py --out folders")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    result = {"command": "python benchmarks/eval_noise.py " + " ".join(map(str, args.records))
              + f" --out {args.out}", "records": []}  # fmt: skip
    lines = ["# Evaluation noise against model noise (validation goals)", "",
             f"`{result['command']}` (the method: the script's docstring).", "",
             "| record | backbone | step | models x seeds | mean return | one rollout's std | "
             "models' std | std with R = " + " / ".join(map(str, ROLLOUTS)) + " |",
             "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for path in args.records:
        record = json.loads((path / "curve.json").read_text())
        tasks = {t for o in record["objectives"].values() for t in o.get("tasks", [])}
        rows = noise(record)
        result["records"].append({"record": str(path), "tasks": sorted(tasks), "rows": rows})
        for r in rows:
            std_r = " / ".join(f"{r['std_of_R'][k]:.2f}" for k in ROLLOUTS)
            lines.append(
                f"| {path.name} | {r['objective'].upper()} | {r['step']:,} | {r['models']} x "
                f"{r['seeds']} | {r['mean_return']:.2f} | {r['rollout_std']:.2f} | "
                f"{r['model_std']:.2f} | {std_r} |"
            )
    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(result, args.out / "rollouts.json")
    write_text_atomic("\n".join(lines) + "\n", args.out / "rollouts.md")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
