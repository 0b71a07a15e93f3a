"""``lhf reproduce``: one paper experiment end to end, stage by stage, to a report."""

from __future__ import annotations

import argparse

from lhf_hf.configs.commands import ReproduceOptions

from .flags import add_params, values

HELP = "run a paper experiment end to end (collect, filter, train, evaluate, compare) to report.md"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "reproduce",
        help=HELP,
        description=HELP + ".  Every stage is cached by its config's hash: a rerun resumes.",
    )
    fields = add_params(p, ReproduceOptions, positional=("experiment",))
    p.set_defaults(func=run, fields=fields)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.reproduce import reproduce  # deferred: heavy (every stage's libraries)

    o = ReproduceOptions(**values(args, args.fields))
    if o.estimate:
        from lhf_hf.reproduce import estimate_experiment  # deferred: heavy, as above

        print(estimate_experiment(o.experiment, o.preset, o.runs, o.work, o.jobs, o.objectives))
        return 0
    reproduce(o.experiment, o.preset, o.runs, o.out, o.work, jobs=o.jobs, objectives=o.objectives)
    return 0
