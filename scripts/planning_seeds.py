"""Planning against the policy over many rollout seeds, per unseen goal.

    python scripts/planning_seeds.py --model runs/tables/train/HASH/model [--seeds 2 3 4 5 6 7]
        [--episodes 40] [--horizons 1 8] [--split-seed N] [--json OUT]

On Darkroom a run's return is decided mostly by which of its 8 unseen goals are found at all (a
goal is found in every late episode or in none), so one rollout seed compares planning and the
policy on luck as much as on skill.  This evaluates the same checkpoint without planning and with
planning at each ``--horizons`` depth (the model's ``plan_horizon`` overridden), each on the same
seeds (the same environments and streams), and writes the whole-curve mean and the per-goal means of
every rollout.  Default split: the model's training dataset's (as ``lhf evaluate``); its validation
goals (``--tasks test --report-on-test``: its test goals, to report a choice already made).
"""

from __future__ import annotations

import argparse

import numpy as np

from lhf_hf.envs import get_spec
from lhf_hf.errors import UserError
from lhf_hf.evaluation.rollout import rollout
from lhf_hf.evaluation.seen import TUNING_PARTS, check_unseen, tuning_tasks
from lhf_hf.evaluation.task_batch import make_task_batch
from lhf_hf.modeling import load_model
from lhf_hf.utils.io import write_json_atomic


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--model", required=True)
    p.add_argument("--seeds", type=int, nargs="+", default=[2, 3, 4, 5, 6, 7])
    p.add_argument("--episodes", type=int, default=40)
    p.add_argument("--horizons", type=int, nargs="+", default=[1, 8])
    p.add_argument("--split-seed", type=int, default=None)
    p.add_argument("--json", default=None)
    p.add_argument("--tasks", default="validation", choices=TUNING_PARTS,
                   help="the goals measured: validation (a model trained on `lhf collect --tasks "
                   "fit` data), or test with --report-on-test")
    p.add_argument("--report-on-test", action="store_true",
                   help="allow --tasks test: reporting a choice already made, not making one")
    a = p.parse_args()
    model = load_model(a.model)
    if model.config.objective != "dicp":
        raise SystemExit(
            f"error: {a.model} is a {model.config.objective} model; planning needs DICP"
        )
    split = a.split_seed if a.split_seed is not None else model.config.split_seed
    if split is None:  # a model saved before its config recorded the split
        raise SystemExit(f"error: {a.model} does not record its split seed: pass --split-seed")
    try:
        tasks = tuning_tasks(model.config.env_id, a.tasks, split, a.report_on_test)
    except UserError as exc:
        raise SystemExit(f"error: {exc}") from None
    check_unseen(get_spec(model.config.env_id), model.config, tasks, split, False, a.model)
    out = {"model": a.model, "split_seed": split, "tasks": tasks, "episodes": a.episodes}
    arms = [("no plan", False, model.config.plan_horizon)]
    arms += [(f"plan depth {h}", True, h) for h in a.horizons]
    for label, plan, horizon in arms:
        model.config.plan_horizon = horizon
        rows = []
        for seed in a.seeds:
            batch = make_task_batch(model.config.env_id, tasks, split, seed)
            r = rollout(model, batch, a.episodes, seed=seed, plan=plan, progress=False)
            rows.append(
                {
                    "seed": seed,
                    "mean": round(float(r.returns.mean()), 3),
                    "per_task": np.round(r.returns.mean(1), 2).tolist(),
                }
            )
            print(label, rows[-1], flush=True)
        out[label] = rows
    means = {k: float(np.mean([r["mean"] for r in out[k]])) for k, _, _ in arms}
    out["mean_over_seeds"] = {k: round(v, 3) for k, v in means.items()}
    print(out["mean_over_seeds"])
    if a.json:
        write_json_atomic(out, a.json)


if __name__ == "__main__":
    main()
