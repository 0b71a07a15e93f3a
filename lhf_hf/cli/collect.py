"""``lhf collect``: collect learning histories into a dataset folder."""

from __future__ import annotations

import argparse
import gc
import os
import sys

from lhf_hf.configs import CollectConfig
from lhf_hf.configs.commands import OutputOptions

from .flags import add_params, values

HELP = (
    "collect learning histories into a LeRobot-style dataset (PPO by the batched collector on the "
    "gridworlds, SB3 PPO/SAC elsewhere; --collector sb3: the SB3 reference)"
)


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("collect", help=HELP, description=HELP)
    # the nested PPO / SAC settings have the env's paper values; set them from Python or a spec
    config = add_params(p, CollectConfig, positional=("env_id",), skip=("ppo", "sac"))
    output = add_params(p, OutputOptions, only=("out", "progress"))
    output += add_params(
        p, OutputOptions, only=("resume", "overwrite"), group=p.add_mutually_exclusive_group()
    )
    p.set_defaults(func=run, config=config, output=output)
    return p


def run(args: argparse.Namespace) -> int:
    from lhf_hf.collection import collect  # deferred: heavy (torch, datasets, SB3)
    from lhf_hf.collection.driver import started_collector  # deferred: as above

    given = values(args, args.config)
    output = OutputOptions(**values(args, args.output))
    default = given.get("collector", "auto") == "auto"
    started = started_collector(output.out) if default and output.resume else None
    config = CollectConfig(**given, **({"collector": started} if started else {}))
    if default:  # said: the default depends on the env (and, resuming, on the folder)
        why = (f"the one {output.out} was started with" if started else
               f"the default for {config.algo.upper()} on {config.env_id}")  # fmt: skip
        if config.collector == "batched":
            why += "; --collector sb3 runs the SB3 reference"
        print(f"collect {config.env_id}: the {config.collector} collector ({why})", file=sys.stderr)
    # A one-shot process: the objects alive now (torch, numpy, datasets, ...) live until exit, so
    # the cyclic GC need not rescan them on every full collection (~0.7 s per Key-to-Door chunk of
    # the batched collector's per-step allocations).
    gc.freeze()
    try:
        ds = collect(
            config,
            output.out,
            resume=output.resume,
            overwrite=output.overwrite,
            progress=output.progress,
        )
    except KeyboardInterrupt:
        print(f"lhf collect: {kept_tasks(config, output.out)}", file=sys.stderr)
        raise
    if ds is not None:
        print(f"wrote {ds}\ncard: {ds.root / 'README.md'}")
    else:  # a non-zero rank under accelerate launch: rank 0 assembles the dataset
        print(
            f"[rank {os.environ.get('RANK', '?')}] committed this rank's tasks; rank 0 wrote the dataset"
        )
    return 0


def kept_tasks(config: CollectConfig, out) -> str:
    """What an interrupted collection keeps for ``--resume``: its finished tasks (tasks are written
    a chunk at a time, so an interrupt inside the first chunk keeps none)."""
    from lhf_hf.histories.writer import task_done  # deferred: heavy (pyarrow)

    rows = config.histories * config.steps
    done = sum(task_done(out, p, rows) for p in range(len(config.tasks)))
    if done:
        return f"{done} of {len(config.tasks)} tasks are kept: --resume continues from them"
    per_chunk = min(config.tasks_per_chunk or len(config.tasks), len(config.tasks))
    chunk = "" if config.collector == "sb3" else (
        f" (the batched collector writes {per_chunk} tasks at a time: --tasks-per-chunk sets how many)"
    )  # fmt: skip
    return f"no task had finished, so --resume starts over{chunk}"
