"""``lhf envs``: list the registered environments (table or JSON), optionally with an oracle tour."""

from __future__ import annotations

import argparse
import json
import sys

from lhf_hf.configs.commands import EnvsOptions

from .flags import add_params, values

HELP = "list environments (id, horizon, tasks, split and validation sizes, spaces, optimal returns)"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("envs", help=HELP, description=HELP)
    fields = add_params(p, EnvsOptions)
    p.set_defaults(func=run, fields=fields)
    return p


def collect(oracle: bool = False, split_seed: int = 0, metaworld_tasks: int = 2) -> list[dict]:
    """Rows of ``lhf envs`` (importable: the CLI only formats them)."""
    from lhf_hf.envs import get_spec, list_env_ids  # deferred: heavy
    from lhf_hf.envs.oracle import oracle_report  # deferred: heavy

    rows = []
    for env_id in list_env_ids():
        spec = get_spec(env_id)
        row = spec.summary()
        if oracle:
            try:
                row["oracle"] = oracle_report(
                    env_id,
                    split_seed,
                    # an oracle without a closed-form optimum rolls out a policy: cap
                    max_tasks=metaworld_tasks if spec.optimal_returns is None else None,
                )
            except ImportError as exc:  # the metaworld extra is optional
                row["oracle"] = {"skipped": str(exc)}
        rows.append(row)
    return rows


def _format_table(rows: list[dict]) -> str:
    def opt(r):
        o = r["optimal_return"]
        if o is None:
            return "success rate"
        return (
            f"{o['min']:g}"
            if o["min"] == o["max"]
            else f"{o['min']:g}..{o['max']:g} (mean {o['mean']:.2f})"
        )

    def oracle(r):
        o = r.get("oracle")
        if o is None:
            return None
        if "skipped" in o:
            return "skipped (no metaworld extra)"
        if "mean_return" in o:
            return f"{o['mean_return']:.2f}/{o['mean_optimal_return']:.2f} ({o['tasks_at_optimum']}/{o['tasks']} optimal)"
        return f"success {o['success_rate']:.0%} of {o['tasks']}"

    header = [
        "id",
        "horizon",
        "tasks",
        "train/test",
        "validation",  # held-out train tasks (EnvSpec.validation_split): part of the train count
        "state space",
        "action space",
        "optimal return",
    ]
    table = [
        [
            r["env_id"],
            str(r["horizon"]),
            str(r["num_tasks"]),
            f"{r['num_train_tasks']}/{r['num_test_tasks']}",
            f"{r['num_validation_tasks']} of train",
            r["state_space"],
            r["action_space"],
            opt(r),
        ]
        for r in rows
    ]
    if any("oracle" in r for r in rows):
        header.append("oracle on test tasks")
        for line, r in zip(table, rows, strict=True):
            line.append(oracle(r))
    widths = [max(len(h), *(len(line[i]) for line in table)) for i, h in enumerate(header)]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    out = [fmt.format(*header), fmt.format(*("-" * w for w in widths))]
    out += [fmt.format(*line) for line in table]
    return "\n".join(out)


def run(args: argparse.Namespace) -> int:
    o = EnvsOptions(**values(args, args.fields))
    rows = collect(o.oracle, o.split_seed, o.metaworld_tasks)
    if o.json:
        json.dump(rows, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(_format_table(rows))
    return 0
