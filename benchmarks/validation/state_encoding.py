"""DICP's state encoding on the validation goals: ours (``coordinates``) against the reference's
(``cells``: one 81-way one-hot and an 81-way next-state head, jaehyeon-son/dicp), one DICP each
with everything else equal, evaluated without planning and with the reference planner.

    python benchmarks/validation/state_encoding.py \
        --evals results/validation/dicp_steps/step-4000 results/validation/state_encoding/cells \
        --labels coordinates cells --modes policy ref --margin 0.98 \
        --out results/validation/state_encoding

Each ``--evals`` prefix P names the evaluations ``P-MODE/eval_results.json`` (``lhf evaluate``
on the same validation goals and rollouts).  Per mode: each encoding's whole-curve return, and
within goals the second minus the first (each goal's mean over its rollouts), with the 95 %
t-interval over the goals.  The rule, fixed before the cells model was trained: the departure
(the first, ours) is kept only where it is ahead of the reference's (the second) by more than
``--margin`` (the spread between trained models, results/validation/rollouts) in some mode;
else the reference's encoding is the choice.  Writes ``state_encoding.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy import stats

from lhf_hf.utils.io import read_json, write_json_atomic, write_text_atomic


def goal_means(path: Path) -> tuple[list[int], np.ndarray, str | None]:
    """An evaluation's goals, each goal's whole-curve mean over its rollouts, and the fingerprint
    of the dataset its model trained on."""
    r = read_json(path / "eval_results.json")
    returns = np.asarray(r["returns"], dtype=float)  # (rollouts * goals, episodes), rollout-major
    data = ((r.get("model") or {}).get("dataset") or {}).get("fingerprint")
    means = returns.reshape(r["rollouts"], len(r["tasks"]), -1).mean(axis=(0, 2))  # (goals,)
    return list(r["tasks"]), means, data


def compare(prefixes: list[str], labels: list[str], modes: list[str], margin: float) -> dict:
    rows, data = [], set()
    for mode in modes:
        (goals_a, a, data_a), (goals_b, b, data_b) = (
            goal_means(Path(f"{p}-{mode}")) for p in prefixes
        )
        data |= {data_a, data_b}
        if goals_a != goals_b:
            raise SystemExit(f"{mode}: the two evaluations ran other goals ({goals_a}, {goals_b})")
        diff = b - a  # (goals,): the reference's minus ours
        half = stats.t.ppf(0.975, len(diff) - 1) * diff.std(ddof=1) / np.sqrt(len(diff))
        rows.append({"mode": mode, labels[0]: float(a.mean()), labels[1]: float(b.mean()),
                     "diff": float(diff.mean()), "ci95": [float(diff.mean() - half),
                     float(diff.mean() + half)], "goals_up": int((diff > 0).sum()),
                     "goals": len(diff)})  # fmt: skip
    keep_ours = any(-row["diff"] > margin for row in rows)
    # one collection config gives other draws on a CPU of another instruction set
    # (docs/histories.md): two models on two draws differ by their data as well
    return {"labels": labels, "margin": margin, "rows": rows, "same_data": len(data) == 1,
            "choice": labels[0] if keep_ours else labels[1]}  # fmt: skip


def render(found: dict) -> str:
    first, second = found["labels"]
    lines = [
        f"# DICP's state encoding on the validation goals: {first} (ours) against {second}",
        "",
        f"| mode | {first} | {second} | {second} - {first} within goals (95% CI) | goals "
        f"{second} ahead |",
        "|---|---|---|---|---|",
    ]
    for row in found["rows"]:
        lo, hi = row["ci95"]
        lines.append(f"| {row['mode']} | {row[first]:.2f} | {row[second]:.2f} | "
                     f"{row['diff']:+.2f} ({lo:+.2f} .. {hi:+.2f}) | {row['goals_up']} of "
                     f"{row['goals']} |")  # fmt: skip
    lines += ["", f"Rule: {first} (a departure) is kept only if it is ahead by more than "
              f"{found['margin']:g} in some mode. Choice: **{found['choice']}**.", ""]  # fmt: skip
    if not found["same_data"]:
        lines += ["The two models trained on two draws of one collection config (other datasets "
                  "by fingerprint, e.g. collected on CPUs of other instruction sets): their "
                  "difference holds the data's draw too.", ""]  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--evals", nargs=2, required=True, metavar="PREFIX")
    p.add_argument("--labels", nargs=2, default=["coordinates", "cells"])
    p.add_argument("--modes", nargs="+", default=["policy", "ref"])
    p.add_argument("--margin", type=float, default=0.98)
    p.add_argument("--out", required=True)
    args = p.parse_args()
    found = compare(args.evals, args.labels, args.modes, args.margin)
    out = Path(args.out)
    write_json_atomic(found, out / "state_encoding.json")
    write_text_atomic(render(found), out / "state_encoding.md")
    print(render(found))


if __name__ == "__main__":
    main()
