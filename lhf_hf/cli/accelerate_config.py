"""``lhf accelerate-config``: the path of the shipped accelerate config, for ``accelerate launch``."""

from __future__ import annotations

import argparse

from lhf_hf.utils.launcher import accelerate_config

HELP = "print the path of the accelerate config for CPU data parallelism (2 processes, gloo)"
DESCRIPTION = (
    HELP + '. Use it as `accelerate launch --config_file "$(lhf accelerate-config)" -m lhf_hf '
    "train ...` (--num_processes N for another count); copy it to edit it. It ships with lhf_hf: "
    "`accelerate launch --cpu --num_processes 2` runs ONE process."
)


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("accelerate-config", help=HELP, description=DESCRIPTION)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    print(accelerate_config())
    return 0
