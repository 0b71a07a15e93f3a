"""The reference rates of ``lhf reproduce --estimate``, from finished stages on this machine.

    python benchmarks/reference_rates.py WORK [WORK ...] [--out lhf_hf/reproduce/rates.json] [--merge | --replace]
        [--only PATTERN ...]

Reads every ``stage.json`` under the given stage caches that recorded its cost and ran on this
CPU model (``estimate.measured``), and writes the seconds over units of each key, with the units and
stages behind it, as this machine's table in ``--out``; the tables of other machines there are kept
(``--estimate`` takes this CPU model's table first, ``estimate.reference_rates``).  ``--merge`` adds
the stages to this machine's table instead of replacing it (a rate measured in both is pooled,
weighed by its units); ``--replace`` keeps this machine's table but for the keys measured here,
whose rates these stages replace (a re-calibration of some kinds of stage); ``--only`` takes the
keys matching these shell patterns only (``'train|*' 'evaluate|*|plan|*'``: a calibration's short
collections and 1-episode evaluations are mostly start-up, its trainings and planned evaluations
are not).  The shipped table was made from ``benchmarks/calibration/*.yaml``
(BENCHMARKS.md names the commands).
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import time
from fnmatch import fnmatchcase
from pathlib import Path

from lhf_hf.collection.backend_verdict import cpu_model
from lhf_hf.reproduce.estimate import REFERENCE, measured
from lhf_hf.utils.io import read_json, write_json_atomic


def merge_rates(old: list[dict], new: list[dict]) -> list[dict]:
    """Two tables' rates as one: a key in both gets the seconds of all their stages over all their
    units (a rate without ``units`` is weighed by its stages); the start-up time, where a table
    has one, is the mean over stages."""
    pooled: dict[str, dict] = {}
    for r in [*old, *new]:
        p = pooled.get(r["key"])
        if p is None:
            pooled[r["key"]] = dict(r)
            continue
        w_old, w_new = (
            (p["units"], r["units"])
            if "units" in p and "units" in r
            else (p["stages"], r["stages"])
        )
        p["seconds_per_unit"] = (p["seconds_per_unit"] * w_old + r["seconds_per_unit"] * w_new) / (
            w_old + w_new
        )
        if "overhead_s" in p or "overhead_s" in r:
            p["overhead_s"] = (
                p.get("overhead_s", 0.0) * p["stages"] + r.get("overhead_s", 0.0) * r["stages"]
            ) / (p["stages"] + r["stages"])
        p["stages"] += r["stages"]
        if "units" in p and "units" in r:
            p["units"] += r["units"]
        else:
            p.pop("units", None)
    return [pooled[k] for k in sorted(pooled)]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("work", nargs="+", help="stage caches (lhf reproduce --work)")
    p.add_argument("--out", default=str(REFERENCE))
    how = p.add_mutually_exclusive_group()
    how.add_argument("--merge", action="store_true", help="add to this machine's table in --out")
    how.add_argument(
        "--replace", action="store_true", help="replace only the keys measured here in that table"
    )
    p.add_argument("--only", nargs="+", metavar="PATTERN", help="only keys matching these patterns")
    a = p.parse_args()
    for w in a.work:
        if not w.strip() or not Path(w).is_dir():
            raise SystemExit(f"{w!r}: not a stage cache folder (lhf reproduce --work)")
    out, cpu = Path(a.out), cpu_model()
    try:  # read (and refused when it is not a table) before any work
        machines = read_json(out)["machines"] if out.exists() else []
        if not isinstance(machines, list) or not all(
            isinstance(m.get("rates"), list) for m in machines
        ):
            raise ValueError("not a list of machine tables")
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
        raise SystemExit(f"{out}: not a rates table ({e}); pass another --out") from None
    found: dict[str, dict] = {}
    for w in a.work:
        for key, m in measured(w, cpu).items():
            f = found.setdefault(key, {"seconds": 0.0, "units": 0.0, "stages": 0})
            for k in f:
                f[k] += m[k]
    if a.only:
        found = {k: f for k, f in found.items() if any(fnmatchcase(k, x) for x in a.only)}
    if not found:
        raise SystemExit(f"no finished stage with a recorded cost on {cpu} under {a.work}"
                         + (f" matching {a.only}" if a.only else ""))  # fmt: skip
    rates = [{"key": k, "seconds_per_unit": f["seconds"] / f["units"], "units": f["units"],
              "stages": f["stages"]} for k, f in sorted(found.items())]  # fmt: skip
    command = "python benchmarks/reference_rates.py " + " ".join(a.work)
    command += " --only " + " ".join(shlex.quote(x) for x in a.only) if a.only else ""
    old = next((m for m in machines if m.get("cpu") == cpu), None)
    if a.merge and old is not None:
        rates = merge_rates(old["rates"], rates)
        command = f"{old.get('command', '?')}; then {command} --merge"
    elif a.replace and old is not None:
        kept = [r for r in old["rates"] if r["key"] not in found]
        rates = sorted([*kept, *rates], key=lambda r: r["key"])
        command = f"{old.get('command', '?')}; then {command} --replace"
    mine = {"cpu": cpu, "machine": f"{platform.machine()}, {os.cpu_count()} cores",
            "date": time.strftime("%Y-%m-%d"), "command": command, "rates": rates}  # fmt: skip
    # in place of this machine's table, so the first machine (the coverage page's) stays first
    at = machines.index(old) if old is not None else len(machines)
    machines[at : at + (old is not None)] = [mine]
    write_json_atomic({"machines": machines}, out)
    for r in rates:
        print(f"{r['key']:<50} {r['seconds_per_unit']:.3e} s/unit ({r['stages']} stage(s))")
    print(f"{len(rates)} rate(s) -> {a.out}")


if __name__ == "__main__":
    main()
