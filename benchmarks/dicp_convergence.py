"""Does the reference planner beat its own policy once DICP has trained long?  (issue 56)

Collects the evaluations of one DICP training's snapshots into ``convergence.json`` and
``convergence.png``: return against training steps for the policy alone, the reference planner
(``--plan``: every step once the context is full), the gated planner (``--plan-gate reward_seen``,
ours) and the planner with the environment's true dynamics (``--plan-dynamics oracle``, the
planner's ceiling), with the DICP paper's Darkroom levels (AD 12.5, DICP 15) as lines.  Per
snapshot it also gives the planner's gain over the policy within goals: each validation goal's
return (mean over its rollouts) with planning minus without, and the 95 % t-interval of that
difference over the goals, so a pooled mean is never the only evidence.

The committed runs it read were made with these commands on the earlier validation goals of split
0 (12, 17, 27, 36, 45, 61, 64, 68: results/FINDINGS.md); the same commands now use the current
ones (``benchmarks/validation/remake.sh dicp`` runs this script on its own trainings)::

    lhf collect darkroom --tasks fit --histories 100 --protocol paper --collector batched \
        --ppo-backend kernel --out data/dr100fit
    OMP_NUM_THREADS=1 lhf train --dataset data/dr100fit --objective dicp --preset paper \
        --max-steps 12000 --batch-size 64 --lr 3e-3 --reward-weighting data --seed 0 \
        --save-steps 500 --out runs/dicp56/baseline        # snapshots copied at log-spaced steps
    lhf evaluate --model SNAPSHOT --tasks validation --episodes 100 --rollouts 4 --seed 0 \
        [--plan [--plan-gate reward_seen] [--plan-reward-threshold P] [--plan-dynamics oracle]] \
        --out EVAL/step-N-MODE          # MODE: policy; ref, refgated, refgatedthreshold99,
        #   reforacle (the reference's ties, the default); made with ties by policy before it existed: plan,
        #   gated, oracle, threshold90, threshold99, gatedthreshold99 (MODES)

then::

    python benchmarks/dicp_convergence.py --evals runs/dicp56/eval-baseline \
        --train-log runs/dicp56/train.log --out results/planning/dicp_convergence
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np
from scipy import stats

from lhf_hf.utils.io import read_json, save_figure_atomic, write_json_atomic

#: folder suffix -> label.  ``ref*`` folders plan with the reference's tie order below depth 0
#: (``--plan-ties index``, the default since 2026-12-06); the others were made before it and break
#: ties by the policy (a variant of ours): ``collect`` checks each folder's config says so.
MODES = {
    "policy": "DICP (policy alone)",
    "ref": "DICP + plan (reference)",
    "refgated": "DICP + plan, gated on a seen reward (ours)",
    "refgatedthreshold99": "DICP + plan, gated, reward p >= 0.99 (ours)",
    "plan": "DICP + plan, ties by policy (ours)",
    "gated": "DICP + plan, gated, ties by policy (ours)",
    "threshold90": "DICP + plan, reward p >= 0.9, ties by policy (ours)",
    "threshold99": "DICP + plan, reward p >= 0.99, ties by policy (ours)",
    "gatedthreshold99": "DICP + plan, gated, reward p >= 0.99, ties by policy (ours)",
    "oracle": "planner with the true dynamics (ties by policy)",
    "reforacle": "planner with the true dynamics (the reference's tie order)",
}
#: the modes the plot draws (the others are in the JSON and the README's tables)
PLOTTED = ("policy", "ref", "refgated", "refgatedthreshold99", "plan", "oracle", "reforacle")
LEVELS = {"AD (DICP paper)": 12.5, "DICP + plan (DICP paper)": 15.0}
_FOLDER = re.compile(r"step-(\d+)-(\w+)$")


def goal_means(result: dict) -> tuple[np.ndarray, np.ndarray]:
    """(whole-curve, last 10 %) return per goal, each the mean over the goal's rollouts.

    ``returns`` rows are rollout-major: row ``r * tasks + i`` is task ``i`` in rollout ``r``."""
    returns = np.asarray(result["returns"], dtype=float)  # (rollouts * tasks, episodes)
    tasks = len(result["tasks"])
    per = returns.reshape(-1, tasks, returns.shape[1])  # (rollouts, tasks, episodes)
    tail = max(1, returns.shape[1] // 10)
    return per.mean(axis=(0, 2)), per[:, :, -tail:].mean(axis=(0, 2))


def explore_exploit(result: dict) -> dict:
    """Exploration and exploitation apart: the share of rollouts (a goal in one rollout) whose
    last 10 % of episodes hold any reward (the goal was found and is returned to), and the mean
    return of those episodes over the rollouts that found it."""
    returns = np.asarray(result["returns"], dtype=float)  # (rollouts * tasks, episodes)
    tail = max(1, returns.shape[1] // 10)
    late = returns[:, -tail:].mean(1)  # (rollouts * tasks,)
    found = late > 0
    return {
        "found": round(float(found.mean()), 4),
        "rollouts": int(len(found)),
        "late_return_when_found": round(float(late[found].mean()), 4) if found.any() else None,
    }


def phantom_rewards(diagnosis: dict, actions: int = 5) -> dict:
    """How often one search meets a reward the true dynamics do not give, from
    ``scripts/diagnose_planning.py --parts depth`` (each seed's beam searches along a model-free
    rollout): per depth d, the candidates per search n_d and their false-positive rate p_d, and
    1 - prod_d (1 - p_d) ** n_d, the chance that a search holds at least one such reward if the
    candidates erred independently (an estimate: errors of one context are correlated)."""
    out = {}
    for seed, depths in diagnosis["by_depth"].items():
        searches = depths["0"]["candidates"] / actions  # depth 0: each action from the state
        n = {d: v["candidates"] / searches for d, v in depths.items()}
        fp = {d: v["reward_false_positive"] for d, v in depths.items()}
        log_none = sum(n[d] * np.log1p(-fp[d]) for d in depths)
        out[seed] = {
            "candidates_per_search": round(sum(n.values()), 1),
            "false_positive_rate_mean": round(
                sum(n[d] * fp[d] for d in depths) / sum(n.values()), 6
            ),
            "p_search_with_phantom_reward": round(float(1 - np.exp(log_none)), 4),
        }
    return out


def paired(a: np.ndarray, b: np.ndarray) -> dict:
    """Mean of ``a - b`` over goals, its 95 % t-interval, and on how many goals it is > 0."""
    d = a - b
    half = (
        stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else np.nan
    )
    return {
        "mean": round(float(d.mean()), 4),
        "ci95": [round(float(d.mean() - half), 4), round(float(d.mean() + half), 4)],
        "goals_better": int((d > 0).sum()),
        "goals_worse": int((d < 0).sum()),
        "goals": len(d),
    }


def collect(evals: Path) -> dict:
    points: dict[int, dict] = {}
    for folder in sorted(evals.iterdir()):
        m = _FOLDER.search(folder.name)
        if not m or not (folder / "eval_results.json").exists():
            continue
        step, mode = int(m.group(1)), m.group(2)
        res = read_json(folder / "eval_results.json")
        ties = res["config"].get("plan_ties", "policy")  # written before the field: by policy
        if res["config"].get("plan") and (ties == "index") != mode.startswith("ref"):
            raise SystemExit(f"{folder}: planned with ties by {ties}, not what {mode!r} names")
        whole, last = goal_means(res)
        points.setdefault(step, {})[mode] = {
            "whole_curve": round(float(whole.mean()), 4),
            "last10": round(float(last.mean()), 4),
            "per_goal_whole_curve": [round(float(x), 4) for x in whole],
            "per_goal_last10": [round(float(x), 4) for x in last],
            "tasks": res["tasks"],
            "rollouts": res.get("rollouts"),
            "episodes": len(res["mean_curve"]),
            "task_label": res.get("task_label"),
            "explore_exploit": explore_exploit(res),
            "planned_steps": res.get("planned_steps"),
            "wall_s": res.get("wall_s"),
            "config": res["config"],
        }
    for modes in points.values():
        if "policy" not in modes:
            continue
        base_w = np.array(modes["policy"]["per_goal_whole_curve"])
        base_l = np.array(modes["policy"]["per_goal_last10"])
        for mode, rec in modes.items():
            if mode != "policy":
                rec["minus_policy"] = {
                    "whole_curve": paired(np.array(rec["per_goal_whole_curve"]), base_w),
                    "last10": paired(np.array(rec["per_goal_last10"]), base_l),
                }
    return dict(sorted(points.items()))


def training_log(log: Path | None) -> dict | None:
    """The training's logged losses (every ``logging_steps``) and its final summary, if given."""
    if log is None or not log.exists():
        return None
    losses, summary = [], None
    for line in log.read_text().splitlines():
        if line.startswith("{'loss'"):
            losses.append(float(re.search(r"'loss': '([\d.e+-]+)'", line).group(1)))
        elif line.startswith("{'train_runtime'"):
            summary = line
    return {"loss_every_logged_step": losses, "summary": summary}


def plot(points: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for ax, key, title in [
        (axes[0], "whole_curve", "mean over the 100 episodes"),
        (axes[1], "last10", "episodes 91-100"),
    ]:
        for mode in PLOTTED:
            label = MODES[mode]
            xs = [s for s in points if mode in points[s]]
            if not xs:
                continue
            ys = [points[s][mode][key] for s in xs]
            per = [np.array(points[s][mode][f"per_goal_{key}"]) for s in xs]
            err = [stats.sem(p) for p in per]
            ax.errorbar(xs, ys, yerr=err, marker="o", capsize=3, label=label)
        for name, level in LEVELS.items():
            ax.axhline(level, ls="--", lw=0.8, color="grey")
            ax.text(min(points), level + 0.15, name, fontsize=7, color="grey")
        ax.set_xscale("log")
        ax.set_xlabel("training steps (batch 64)")
        ax.set_title(title, fontsize=10)
    axes[0].set_ylabel("return (8 validation goals x 4 rollouts)")
    fig.text(0.01, 0.01, "bars: standard error over the goals", fontsize=7)
    axes[0].legend(fontsize=7, loc="lower right")
    fig.suptitle(
        "DICP on Darkroom (paper-protocol data, 100 histories per goal): planning vs policy"
    )
    fig.tight_layout()
    save_figure_atomic(fig, out)  # closes the figure


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--evals", required=True, help="folder of step-N-MODE evaluation folders")
    p.add_argument("--train-log", default=None, help="lhf train's log (losses, summary)")
    p.add_argument(
        "--diagnoses",
        nargs="*",
        default=[],
        help="diagnose_planning.py JSONs of this training's snapshots, named "
        "diagnose-ARM-STEP.json",
    )
    p.add_argument("--out", required=True)
    args = p.parse_args()
    points = collect(Path(args.evals))
    for path in args.diagnoses:
        step = int(re.search(r"-(\d+)\.json$", path).group(1))
        diagnosis = read_json(path)
        if "by_depth" in diagnosis and step in points:
            points[step]["phantom_rewards"] = phantom_rewards(diagnosis)
    if not points:
        raise SystemExit(f"no step-N-MODE evaluations under {args.evals}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(
        {
            "modes": MODES,
            "levels": LEVELS,
            "points": {str(k): v for k, v in points.items()},
            "training": training_log(Path(args.train_log) if args.train_log else None),
        },
        out / "convergence.json",
    )
    plot(points, out / "convergence.png")
    for step, modes in points.items():
        row = ", ".join(
            f"{m} {r['whole_curve']:.2f}/{r['last10']:.2f}"
            + (f" (d {r['minus_policy']['whole_curve']['mean']:+.2f} "
               f"{r['minus_policy']['whole_curve']['ci95']})" if "minus_policy" in r else "")
            + f" found {r['explore_exploit']['found']:.2f}"
            f" late|found {r['explore_exploit']['late_return_when_found']}"
            for m, r in modes.items() if m != "phantom_rewards"
        )  # fmt: skip
        print(f"step {step}: {row}")
        if "phantom_rewards" in modes:
            print(f"  phantom rewards per search: {modes['phantom_rewards']}")
    print(json.dumps(str(out / "convergence.png")))


if __name__ == "__main__":
    main()
