"""``lhf reproduce``: one paper experiment end to end, stage by stage, to a report."""

from __future__ import annotations

import argparse

from lhf_hf.configs.commands import ReproduceOptions

from .flags import add_params, add_progress, progress, values

HELP = "run a paper experiment end to end (collect, filter, train, evaluate, compare) to report.md"


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "reproduce",
        help=HELP,
        description=HELP + ".  Every stage is cached by its config's hash: a rerun resumes.",
    )
    fields = add_params(p, ReproduceOptions, positional=("experiment",))
    add_progress(p)  # every stage's bars (in this process or a --jobs child)
    p.set_defaults(func=run, fields=fields)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.reproduce import reproduce  # deferred: heavy (every stage's libraries)

    o = ReproduceOptions(**values(args, args.fields))
    if o.export_stages is not None:
        from lhf_hf.reproduce import export_experiment  # deferred: heavy, as above

        n = export_experiment(
            o.experiment, o.export_stages, o.preset, o.runs, o.work, o.objectives, o.out
        )
        placeholder = (
            " (FOLDER: a spec named like a shipped one names its report's folder)"
            if " --out FOLDER " in n["command"]
            else ""
        )
        print(
            f"[lhf reproduce] exported to {o.export_stages}: {n['portable']} evaluation(s) and "
            f"{n['records']} record(s) of other finished stages; {n['not_done']} stage(s) of "
            f"the plan are not done in {o.work}. Elsewhere: {n['command']}{placeholder}"
        )
        return 0
    if o.estimate:
        from lhf_hf.reproduce import estimate_experiment  # deferred: heavy, as above

        text = estimate_experiment(
            o.experiment, o.preset, o.runs, o.work, o.jobs, o.objectives, o.import_stages, out=o.out
        )
        print(text)
        return 0
    reproduce(
        o.experiment,
        o.preset,
        o.runs,
        o.out,
        o.work,
        jobs=o.jobs,
        objectives=o.objectives,
        import_from=o.import_stages,
        progress=progress(args),
    )
    return 0
