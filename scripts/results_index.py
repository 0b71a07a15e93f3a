"""Render ROOT/README.md (default ``results/README.md``): every table ``lhf reproduce`` wrote under
ROOT, cell by cell, our E beside the paper's.

    python scripts/results_index.py [--root results] [--coverage {quick,cpu,paper,none}]

First the coverage of one preset: every cell of every shipped spec, done or not, with what is left
to run (``lhf_hf/reproduce/coverage.py``); then every table.

Exits 1 when ROOT is missing, empty, a file or one table's folder, 2 when some table's
``results.json`` could not be read (the index is still written, naming them).
"""

from __future__ import annotations

import argparse
import sys

from lhf_hf.reproduce.experiment import PRESETS
from lhf_hf.reproduce.index import write_index


def main() -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "--root",
        default="results",
        help="the folder holding one folder per table (default: results, from the current folder)",
    )
    p.add_argument(
        "--coverage",
        default="cpu",
        choices=[*PRESETS, "none"],
        help="the preset whose cells of every shipped spec are listed first, done or not, with "
        "what is left to run; 'none': no such list (default: cpu)",
    )
    args = p.parse_args()
    try:
        path, bad = write_index(args.root, None if args.coverage == "none" else args.coverage)
    except (OSError, ValueError) as exc:  # no such folder, a file, one table's folder, ''
        print(exc, file=sys.stderr)
        return 1
    print(path)
    if bad:
        print(f"unreadable results.json in: {', '.join(bad)} (named in {path})", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
