"""Render ``results/README.md``: every table ``lhf reproduce`` wrote, our E beside the paper's.

python scripts/results_index.py [--root results]
"""

from __future__ import annotations

import argparse

from lhf_hf.reproduce.index import write_index


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", default="results", help="the folder holding one folder per table")
    args = p.parse_args()
    try:
        print(write_index(args.root))
    except FileNotFoundError as exc:
        raise SystemExit(str(exc)) from None


if __name__ == "__main__":
    main()
