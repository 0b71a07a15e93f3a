"""``lhf evaluate``: in-context rollouts of a checkpoint on unseen tasks; ``lhf compare``: E tables."""

from __future__ import annotations

import argparse

from lhf_hf.configs import EvalConfig

from .flags import add_params, add_progress, progress, values

HELP = "evaluate a checkpoint in context on unseen tasks (curve, results JSON, model card)"
COMPARE_HELP = "compare baseline and LHF evaluation runs: relative enhancement E, table, figure"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("evaluate", help=HELP, description=HELP)
    fields = add_params(p, EvalConfig, flags={"env_id": "--env"})
    add_progress(p)
    p.set_defaults(func=run, fields=fields)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.evaluation import evaluate  # deferred: heavy (torch, transformers)
    from lhf_hf.evaluation.evaluate import plan_label  # deferred: with it

    cfg = EvalConfig(**values(args, args.fields))
    r = evaluate(cfg, progress=progress(args))
    print(
        f"{r['env_id']}, {r['task_label']} ({len(r['tasks'])} tasks{f' x {cfg.rollouts} rollouts' if cfg.rollouts > 1 else ''}, {cfg.episodes} episode{'s' * (cfg.episodes > 1)}{plan_label(cfg).replace(' + ', ', ')}): "
        f"mean return {r['mean_return']:.3f}, first {r['first_return']:.3f}, final {r['final_return']:.3f}"
        + (f", success {r['success_rate']:.3f}" if r["success_rate"] is not None else "")
        + f"  [{r['env_steps_per_s']:.0f} env-steps/s]"
    )
    print(f"results: {cfg.out}/eval_results.json  curve: {cfg.out}/eval_curve.png")
    return 0
