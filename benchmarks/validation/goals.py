"""Whether a validation record was made on today's validation goals (``remake.sh`` skips those).

    python benchmarks/validation/goals.py check PATH [--splits 0 1 2]   # exit 0: current, 1: not
    python benchmarks/validation/goals.py write DIR [--splits 0 1 2]    # DIR/goals.json: a part done

``PATH`` is a ``bench_icrl_curve.py`` record (``curve.json``: ``objectives.*.tasks``), an ``lhf
evaluate`` result (``eval_results.json``: ``tasks``) or a folder whose ``goals.json`` this script
wrote when its part finished.  Darkroom's validation goals of each split
(``EnvSpec.validation_split``), compared as sets.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from lhf_hf.envs import split_part

ENV = "darkroom"
GOALS_FILE = "goals.json"


def goals(splits: list[int]) -> dict[str, list[int]]:
    """``{split: sorted validation goals}`` as ``goals.json`` records them."""
    return {str(s): sorted(split_part(ENV, "validation", s)) for s in splits}


def recorded(path: Path) -> list[list[int]]:
    """The goal lists ``path`` records (empty when none, or unreadable)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return []
    if not isinstance(data, dict):
        return []
    if path.name == GOALS_FILE:
        return [data.get(str(s)) for s in sorted(data, key=int)] if data else []
    lists = [data.get("tasks")]  # eval_results.json
    lists += [o.get("tasks") for o in (data.get("objectives") or {}).values()]  # curve.json
    return [t for t in lists if isinstance(t, list)]


def current(path: Path, splits: list[int]) -> bool:
    if path.is_dir():
        path = path / GOALS_FILE
        want = list(goals(splits).values())
        return recorded(path) == want
    (want,) = goals(splits[:1]).values()
    found = recorded(path)
    return bool(found) and all(sorted(t) == want for t in found)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("action", choices=["check", "write"])
    p.add_argument("path")
    p.add_argument("--splits", type=int, nargs="+", default=[0])
    args = p.parse_args()
    path = Path(args.path)
    if args.action == "write":
        path.mkdir(parents=True, exist_ok=True)
        tmp = path / f".{GOALS_FILE}.tmp"
        tmp.write_text(json.dumps(goals(args.splits), indent=1) + "\n")
        tmp.replace(path / GOALS_FILE)
        return
    sys.exit(0 if current(path, args.splits) else 1)


if __name__ == "__main__":
    main()
