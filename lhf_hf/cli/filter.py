"""``lhf filter``: LHF (or an ablation) on a history dataset -> a selection (+ a materialised dataset)."""

from __future__ import annotations

import argparse
import json

from lhf_hf.configs import FilterConfig
from lhf_hf.configs.commands import FilterInputs, OutputOptions

from .flags import add_params, values

HELP = (
    "filter a history dataset with LHF: write a selection (and optionally a materialised dataset)"
)


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("filter", help=HELP, description=HELP)
    inputs = add_params(p, FilterInputs, positional=("dataset",))
    config = add_params(p, FilterConfig)
    output = add_params(p, OutputOptions, skip=("resume",))
    p.set_defaults(func=run, inputs=inputs, config=config, output=output)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.filtering.run import run_filter  # deferred: heavy (datasets)

    inputs = FilterInputs(**values(args, args.inputs))
    config = FilterConfig(**values(args, args.config))
    output = OutputOptions(**values(args, args.output))
    summary = run_filter(
        inputs.dataset,
        output.out,
        config,
        materialize=inputs.materialize,
        overwrite=output.overwrite,
        progress=output.progress,
    )
    print(json.dumps(summary, indent=2))
    print(f"selection: {output.out}/selection.parquet  plot: {output.out}/selection.png")
    return 0
