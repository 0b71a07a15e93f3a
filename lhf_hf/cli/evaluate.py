"""``lhf evaluate``: in-context rollouts of a checkpoint on unseen tasks; ``lhf compare``: E tables."""

from __future__ import annotations

import argparse

HELP = "evaluate a checkpoint in context on unseen tasks (curve, results JSON, model card)"
COMPARE_HELP = "compare baseline and LHF evaluation runs: relative enhancement E, table, figure"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("evaluate", help=HELP, description=HELP)
    p.add_argument(
        "--model",
        required=True,
        help="checkpoint folder (`lhf train`) or Hub model repo ORG/NAME[@REV]",
    )
    p.add_argument("--env", default=None, help="env id (default: the model's)")
    p.add_argument("--split-seed", type=int, default=None, help="default: the training dataset's")
    p.add_argument("--tasks", default="test", help="test (default), train, or indices 0,3,7")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--plan", action="store_true", help="DICP planning once the context is full")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--context",
        choices=("cache", "recompute", "window"),
        default="cache",
        help="cache: sliding-window KV cache (default, fast); recompute: the same function "
        "recomputed every step (the reference); window: the reference code's protocol, the last K "
        "transitions re-encoded from scratch every step",
    )
    p.add_argument(
        "--no-cache",
        action="store_const",
        const="recompute",
        dest="context",
        help="= --context recompute",
    )
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.configs import EvalConfig  # deferred: heavy
    from lhf_hf.evaluation import evaluate  # deferred: heavy

    cfg = EvalConfig(
        model=args.model,
        out=args.out,
        env_id=args.env,
        split_seed=args.split_seed,
        tasks=args.tasks,
        episodes=args.episodes,
        plan=args.plan,
        seed=args.seed,
        context=args.context,
    )
    r = evaluate(cfg)
    print(
        f"{r['env_id']} ({len(r['tasks'])} tasks, {cfg.episodes} episodes{', planning' if cfg.plan else ''}): "
        f"mean return {r['mean_return']:.3f}, first {r['first_return']:.3f}, final {r['final_return']:.3f}"
        + (f", success {r['success_rate']:.3f}" if r["success_rate"] is not None else "")
        + f"  [{r['env_steps_per_s']:.0f} env-steps/s]"
    )
    print(f"results: {args.out}/eval_results.json  curve: {args.out}/eval_curve.png")
    return 0
