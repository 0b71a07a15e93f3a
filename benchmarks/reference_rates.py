"""The reference rates of ``lhf reproduce --estimate``, from finished stages on this machine.

    python benchmarks/reference_rates.py WORK [WORK ...] [--out lhf_hf/reproduce/rates.json]

Reads every ``stage.json`` under the given stage caches that recorded its cost (stages finished
by a version with ``--estimate``), keeps those of this machine's CPU model, and writes the seconds
over units of each (key, torch threads) with the number of stages behind it, as this
machine's table in ``--out``: the tables of other machines there are kept (``--estimate`` uses
the one of a like machine, ``estimate.load_reference``).  The shipped
table was made from ``benchmarks/calibration/gridworlds.yaml`` (short stages of every kind),
``benchmarks/calibration/planning.yaml`` and ``darkroom-half --preset quick`` (a derivation,
lightweight models), then ``benchmarks/calibration/metaworld.yaml`` added with ``--merge``;
BENCHMARKS.md names the commands.  The start-up part of each stage (imports,
loading, saving) is told apart from the part that scales (``estimate.work_seconds``), so short
calibration stages give usable rates.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

from lhf_hf.collection.backend_verdict import cpu_model, instruction_set
from lhf_hf.reproduce.estimate import (
    REFERENCE,
    measured_stages,
    plural,
    rate_table,
    rate_threads,
    reference_machines,
    same_machine,
)
from lhf_hf.utils.io import write_json_atomic


def merge_rates(old: list[dict], new: list[dict]) -> list[dict]:
    """The older table with the new stages added: a (key, threads) measured in both gets the rate
    of all their stages, one measured in only one table keeps its rate.  A rate is seconds over
    units (``estimate.rate_table``), so two are pooled weighed by their ``units``; a rate that
    does not record them (tables made before it was recorded) is weighed by its stages, as is the
    start-up time (a mean over stages).  A collection's, derivation's or filter's rate is one
    whatever thread count either table filed it under (``rate_threads``)."""
    pooled: dict[tuple[str, int], dict] = {}
    for given in [*old, *new]:
        k = (given["key"], rate_threads(given["key"], int(given["threads"])))
        r = {**given, "threads": k[1]}
        if k not in pooled:
            pooled[k] = r
            continue
        p, n = pooled[k], pooled[k]["stages"] + r["stages"]
        by_units = "units" in p and "units" in r
        w_old, w_new = (p["units"], r["units"]) if by_units else (p["stages"], r["stages"])
        p["seconds_per_unit"] = (p["seconds_per_unit"] * w_old + r["seconds_per_unit"] * w_new) / (
            w_old + w_new
        )
        # the start-up is optional in a table (0 when not measured, as ``find_rate`` reads it)
        p["overhead_s"] = (
            p.get("overhead_s", 0.0) * p["stages"] + r.get("overhead_s", 0.0) * r["stages"]
        ) / n
        p["stages"] = n
        if by_units:
            p["units"] = w_old + w_new
        else:
            p.pop("units", None)  # a rate weighed partly by stages: its units are not all known
    return [pooled[k] for k in sorted(pooled)]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("work", nargs="+", help="stage caches (lhf reproduce --work)")
    p.add_argument("--out", default=str(REFERENCE))
    p.add_argument(
        "--merge",
        action="store_true",
        help="add the given caches' stages to this machine's table in --out (a calibration of one "
        "env added to an older table: a rate measured in both is pooled, weighed by its "
        "units) instead of replacing it; a cache already counted there would count twice",
    )
    a = p.parse_args()
    for w in a.work:  # an empty name would scan the current folder, a typo nothing at all
        if not w.strip() or not Path(w).is_dir():
            raise SystemExit(f"{w!r}: not a stage cache folder (lhf reproduce --work)")
    cpu, isa = cpu_model(), instruction_set()
    out = Path(a.out)
    # the table in --out is read (and refused when it is not one) before any work
    if out.exists() and not out.is_file():
        raise SystemExit(f"{out}: not a file; pass a rates table's path as --out")
    try:
        others = reference_machines(json.loads(out.read_text())) if out.exists() else []
    except (OSError, ValueError) as e:
        raise SystemExit(f"{out}: not a rates table ({e}); pass another --out") from None
    records = [r for w in a.work for r in measured_stages(w) if same_machine(r, cpu, isa)]
    if not records:
        raise SystemExit(f"no finished stage with a recorded cost on {cpu} ({isa}) under {a.work}")
    table = rate_table(records)
    rates = [{"key": k, "threads": t, **v} for (k, _, t), v in sorted(table.items())]
    command = "python benchmarks/reference_rates.py " + " ".join(a.work)

    # A machine is its CPU model and instruction set (``same_machine``).  Two tables of this
    # machine (one written before tables recorded the instruction set) become one: with --merge
    # their rates pool, else this machine's new table replaces both.
    olds = [m for m in others if same_machine(m, cpu, isa)]
    date = time.strftime("%Y-%m-%d")
    if a.merge and olds:
        merged = olds[0]["rates"]
        for m in olds[1:]:
            merged = merge_rates(merged, m["rates"])
        rates = merge_rates(merged, rates)
        command = "; ".join(m.get("command", "?") for m in olds) + f"; then {command} --merge"
        dates = [str(m["date"]) for m in olds if m.get("date")]
        if dates:  # when each part was measured
            joined = ", ".join(dates)
            date = joined if joined.endswith(date) else f"{joined}, merged {date}"
        if len(olds) > 1:
            print(f"{len(olds)} tables of this machine in {out}: pooled into one")
    elif olds:
        n_old = sum(len(m["rates"]) for m in olds)
        print(f"replacing this machine's {plural(n_old, 'rate')} in {out} (--merge adds to them)")
    mine = {
        "cpu": cpu,
        "isa": isa,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "date": date,
        "command": command,
        "rates": rates,
    }
    # in place of the first table of this machine, so the first machine (the coverage page's
    # reference) stays first; this machine's other tables went into it
    first = next((i for i, m in enumerate(others) if same_machine(m, cpu, isa)), len(others))
    machines = [m for i, m in enumerate(others) if i < first or not same_machine(m, cpu, isa)]
    machines.insert(first, mine)
    write_json_atomic({"machines": machines}, out)
    for r in rates:
        print(
            f"{r['key']:<50} {r['threads'] or 'any'} thread(s) {r['seconds_per_unit']:.3e} s/unit "
            f"+ {r.get('overhead_s', 0.0):.1f} s start-up ({plural(r['stages'], 'stage')})"
        )
    print(
        f"{plural(len(rates), 'rate')} ({len(table)} from {plural(len(records), 'stage')} now) "
        f"-> {a.out}"
    )


if __name__ == "__main__":
    main()
