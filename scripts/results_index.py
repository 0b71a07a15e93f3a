"""Render ROOT/README.md (default ``results/README.md``): every table ``lhf reproduce`` wrote under
ROOT, cell by cell, our E beside the paper's.

    python scripts/results_index.py [--root results] [--coverage {quick,cpu,paper,none}]

First the coverage of one preset: every cell of every shipped spec, done or not, with what is left
to run (``scripts/results_coverage.py``); then per table its command and budget, one row per env x
arm x backbone with our E (+/- its std over paired runs, and its 95 % confidence interval), the
paper's E, the minimum detectable E (``detectable_e``: the E that the verdict's test finds with
80 % power at the spread of the cell's paired differences; an E below it needs more runs), the verdict (``report.verdict``, or ``judged`` for a table made before it) and the
whole-curve returns without and with LHF.
Tables written before a field existed show ``-`` there.

Exits 1 when ROOT is missing, empty, a file or one table's folder, 2 when some table's
``results.json`` could not be read (the index is still written, naming them).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from urllib.parse import quote

import numpy as np
from results_coverage import coverage as cells_of
from results_coverage import named, render_coverage
from results_coverage import recorded_number as _num

from lhf_hf.errors import NotFoundError, UserError
from lhf_hf.evaluation.compare import detectable_difference, paired_statistics
from lhf_hf.reproduce.experiment import PRESETS, shadows_shipped, train_settings
from lhf_hf.reproduce.report import (
    command_line,
    default_out,
    judge,
    objective_of,
    percent,
    verdict,
)
from lhf_hf.utils.io import read_json, write_text_atomic

INDEX_FILE = "README.md"


def _pair(x) -> tuple[float, float] | None:
    """A recorded interval ``[lo, hi]`` of finite floats, or None."""
    if not isinstance(x, list | tuple) or len(x) != 2:
        return None
    lo, hi = _num(x[0]), _num(x[1])
    return None if lo is None or hi is None else (lo, hi)


def judged(e: float | None, std: float | None, ci, diff_ci) -> str:
    """A recorded row's verdict: ``report.verdict`` where the paired return differences were
    recorded (``diff_ci``); tables made before that are judged on the 95% interval of the per-run
    E (``ci``), and older ones on E against its std over the runs."""
    if diff_ci is None and e is None:  # E undefined (a baseline return of 0) or not recorded
        return "undefined (no finite E)"
    if diff_ci is None and ci is not None:
        said = judge(ci, "the 95% CI spans 0")
        return said if "(" in said else f"{said} (E's 95% CI; no paired test recorded)"
    if diff_ci is None and std is not None:
        if abs(e) <= std:
            return "no clear effect (|E| within its std)"
        return f"{'helps' if e > 0 else 'hurts'} (|E| beyond its std; no paired test recorded)"
    return verdict({"E": e, "diff_ci95": diff_ci})


def detectable_e(r: dict) -> float | None:
    """The cell's minimum detectable E (80 % power, the verdict's test): recorded, else from the
    recorded run means of tables made before it was (None: fewer than 2 paired runs)."""
    if (mde := _num(r.get("E_mde80"))) is not None:
        return mde
    b, f = (r.get(k) for k in ("baseline_run_means", "lhf_run_means"))
    if not isinstance(b, list) or not isinstance(f, list) or len(b) != len(f) or len(b) < 2:
        return None
    b, f = np.asarray(b, float), np.asarray(f, float)
    if not (np.isfinite(b).all() and np.isfinite(f).all()) or b.mean() == 0:
        return None
    return detectable_difference(f - b) / float(b.mean())


def _run_means(r: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """A row's recorded paired run means (baseline, LHF), or None (unrecorded, unpaired, or not
    finite)."""
    b, f = (r.get(k) for k in ("baseline_run_means", "lhf_run_means"))
    if not isinstance(b, list) or not isinstance(f, list) or len(b) != len(f) or len(b) < 2:
        return None
    if any(_num(x) is None for x in (*b, *f)):
        return None
    return np.asarray(b, float), np.asarray(f, float)


def restated(r: dict) -> dict:
    """``r`` with its statistics recomputed from its recorded run means by today's definitions
    (``compare.paired_statistics``: E's sample std, the delta-method interval of the E printed,
    the paired test), so every table reads alike: tables made before them recorded a population
    std and the interval of the mean per-run E.  A row without run means keeps what it recorded,
    marked ``recorded_kind``."""
    means = _run_means(r)
    if means is None:
        kept = any(r.get(k) is not None for k in ("E_std", "E_ci95"))
        return {**r, "recorded_kind": kept}
    return {**r, **paired_statistics(*means), "recorded_kind": False}


def _row(label: str, env_id: str, r: dict, paper: dict) -> str:
    r = restated(r)
    e, std = _num(r.get("E")), _num(r.get("E_std"))
    lo, hi = _pair(r.get("E_interval95") or r.get("E_ci95")) or (None, None)

    p = _num((paper.get(env_id) or {}).get(objective_of(r["backbone"])))
    shown = std is not None or lo is not None
    old = (
        " (as recorded: population std, interval of the mean per-run E)"
        if r["recorded_kind"] and shown
        else ""
    )
    diff_ci = _pair(r.get("diff_ci95"))
    interval = (lo, hi) if lo is not None and hi is not None else None
    reading = judged(e, std, interval, diff_ci).replace("|", "\\|")  # a pipe ends a table cell
    returns = [_num(r.get(k)) for k in ("baseline_mean", "lhf_mean")]
    diff = _num(r.get("diff"))
    paired = (
        f" (difference {diff:+.2f}, 95% CI {diff_ci[0]:+.2f} .. {diff_ci[1]:+.2f})"
        if diff is not None and diff_ci is not None
        else ""
    )
    return (
        f"| {label} | {r['backbone']} | {percent(e)}{f' ± {100 * std:.1f}' if std is not None else ''}{old}"
        f" | {f'{percent(lo)} .. {percent(hi)}' if lo is not None and hi is not None else '-'}"
        f" | {'-' if p is None else f'{p:+.1f}'} | {percent(detectable_e(r))} | {reading}"
        f" | {' -> '.join('-' if x is None else f'{x:.2f}' for x in returns)}{paired} |"
    )


def _table(folder: Path, summary: dict) -> list[str]:
    exp = summary["experiment"]
    paper = exp.get("paper") or {}
    title = exp.get("title", exp["name"])
    report = folder / "report.md"
    head = f"[{title}]({quote(folder.name)}/report.md)" if report.exists() else title
    hours = _num(summary.get("stage_s"))
    narrowed = exp["objectives"] if exp.get("narrowed") else None
    # a table kept beside the command's default folder (another budget), or under a root that is
    # not ``results/``: --out names it, relative to the folder that holds the root, as the default
    # ``results/NAME`` is to the repository (``abspath``: a root given as ``.`` has no name; not
    # ``resolve``, which would follow a symlinked ``results`` to wherever it points)
    default = Path(default_out(exp["name"], exp["preset"], narrowed))
    parent = Path(os.path.abspath(folder)).parent.name
    own = (
        (parent, folder.name) == (default.parent.name, default.name)
        and not shadows_shipped(exp["name"], exp.get("spec"))
    )  # fmt: skip
    where = None if own else f"{parent}/{folder.name}"
    # a custom spec is named by its path (``spec``; tables before it was recorded: the name)
    facts = [
        f"`{command_line(exp['name'], exp['preset'], exp['runs'], narrowed, where, exp.get('spec'))}`"
    ]
    facts += [f"{hours / 3600:.2f} h of stage time"] if hours else []
    # A preset's budget changes over time (the cpu presets went from 50 to 100 histories per goal):
    # the recorded sizes tell tables made by the same command line apart.
    facts += _budget(exp)
    facts += [str(summary["created"])] if summary.get("created") else []
    lines = [
        f"## {head}",
        "",
        "; ".join(facts) + ".",
        "",
        "| env | backbone | E (%) ± std | 95% CI | paper E (%) | detectable E (%) | verdict | return without -> with LHF |",
        "|---|---|---|---|---|---|---|---|",
    ]
    rows = 0
    for cell in summary["cells"]:
        label = cell["env_id"] + ("" if cell["arm"] == "lhf" else f" ({cell['arm']})")
        rows_named = [named(r, summary, cell["env_id"]) for r in cell["rows"]]
        planned = any(" + plan" in r["backbone"] for r in rows_named)
        for row in rows_named:
            # the paper's DICP values are the reference planner's: beside `DICP + plan` only, or
            # beside DICP where nothing planned; never beside a variant of ours
            b = row["backbone"]
            theirs = objective_of(b) != "dicp" or b == ("DICP + plan" if planned else "DICP")
            lines.append(_row(label, cell["env_id"], row, paper if theirs else {}))
            rows += 1
    if not rows:
        lines = lines[:-2] + ["No cells: the table compared nothing."]
    return lines + _kept_line(summary.get("selections") or []) + [""]


def _budget(exp: dict) -> list[str]:
    """``["100 histories per goal", "3,000 training steps"]`` (``"ad 3,000 / dicp 4,000 training
    steps"`` when the table's backbones differ) from the recorded experiment config; nothing for
    what it does not hold."""
    out = []
    histories = (exp.get("collect") or {}).get("histories")
    if isinstance(histories, int):
        out.append(f"{histories} histories per goal")
    train = exp.get("train") or {}
    steps = {o: train_settings(train, o).get("max_steps") for o in exp.get("objectives") or []}
    steps = {o: n for o, n in steps.items() if isinstance(n, int)}
    if len(set(steps.values())) > 1:
        out.append(" / ".join(f"{o} {n:,}" for o, n in steps.items()) + " training steps")
    elif steps:
        out.append(f"{next(iter(steps.values())):,} training steps")
    return out


def _kept_line(selections: list[dict]) -> list[str]:
    """One line per env and arm: the mean return of the histories LHF kept vs rejected, averaged
    over runs (tables made before the report recorded it have none)."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for s in selections:
        groups.setdefault((s["env_id"], s["arm"]), []).append(s)
    out = []
    for (env, arm), runs in groups.items():
        kept = [_num(s.get("mean_return_selected_unique")) for s in runs]
        rejected = [_num(s.get("mean_return_rejected")) for s in runs]
        if None in kept:
            continue
        rej = [r for r in rejected if r is not None]
        out.append(
            f"LHF kept on {env}{'' if arm == 'lhf' else f' ({arm})'}: histories with mean return "
            f"{sum(kept) / len(kept):.2f} vs {sum(rej) / len(rej):.2f} for those it rejected "
            f"(mean over {len(runs)} run(s))."
            if rej
            else f"LHF kept every history on {env} ({len(runs)} run(s))."
        )
    return ["", *out] if out else []


def render_index(root: str | Path, coverage: str | None = None) -> tuple[str, list[str]]:
    """The index of every ``*/results.json`` under ``root`` (one table each), as markdown, and the
    names of the tables whose ``results.json`` could not be read (by the index, or by the coverage
    when its settings or cells are malformed).  ``coverage``: a preset whose cells of every shipped
    spec are listed first, done or not (``coverage.py``)."""
    if not str(root).strip():  # '' would be the current folder
        raise UserError("the results folder (--root) is empty: name it")
    root = Path(root)
    if root.exists() and not root.is_dir():
        raise NotADirectoryError(f"{root} is a file, not a results folder")
    if not root.is_dir():
        raise NotFoundError(f"no results folder {root}")
    where = Path(os.path.abspath(root))  # not resolve(): a symlinked root keeps its name
    if (root / "results.json").exists():  # its README.md would sit beside one table's report
        raise UserError(
            f"{root} is one table's folder (it holds results.json): give the folder that holds "
            f"the tables, {where.parent}"
        )
    folders = sorted(p.parent for p in root.glob("*/results.json"))
    lines = [
        "# Reproduced tables",
        "",
        "Every table `lhf reproduce` wrote under this folder (`scripts/results_index.py` renders this "
        "page from their `results.json`). E = (whole-curve mean return with LHF - without) / without, "
        "the returns averaged over the runs; ± is the sample std of the per-run E over paired runs "
        "(same seed and split), the interval the 95% interval of the E printed (the delta method on "
        "the paired run means). Both, the verdict and the detectable E are recomputed here from "
        "each table's recorded run means, so every table reads alike (tables made before these "
        "definitions recorded a population std and the interval of the mean per-run E); a table "
        "that recorded no run means shows what it recorded, marked so, and `-` where it recorded "
        "nothing. A planned row made before the planner took the reference DICP code's tie order "
        "(2026-12-06) is named `ties by policy`: its beam search broke ties below depth 0 by the "
        "policy, a variant of ours (docs/evaluation.md); one made before the reference's depth-0 "
        "order (2026-12-01) is also named `argmax order`. The verdict is the paired t-test on the "
        "runs' return differences (LHF - baseline): an effect counts only when their mean's 95% "
        "confidence interval, shown after the returns, excludes 0 (a per-run E divides by that "
        "run's baseline return, so one weak baseline widens E's interval whatever the differences "
        "are). A table that recorded no run means is judged on E's interval, and one that recorded "
        "no interval on |E| against its std. The detectable E is the smallest E the verdict's test "
        "finds with 80% power at the spread of the cell's paired differences: an effect below it "
        "needs more runs before a verdict can show it (`-` with fewer than 2 paired runs)."
        + (
            ""
            if where.name == "results"
            else f" The command lines run from the folder that holds `{where.name}/`."
        ),
        "",
    ]
    body: list[str] = []
    if not folders:
        body.append(f"No tables yet: `lhf reproduce EXPERIMENT --out {root}/NAME` writes one.")
    bad = []
    for folder in folders:
        try:
            body += _table(folder, read_json(folder / "results.json"))
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            body += [f"## {folder.name}", "", f"`results.json` unreadable: {exc!r}", ""]
            bad.append(folder.name)
    if coverage is not None:  # the tables this index cannot read are not counted there either
        cov = cells_of(root, coverage, unreadable=bad)
        lines += render_coverage(cov)
        bad += [name for name in cov["malformed_names"] if name not in bad]
    lines += body
    return "\n".join(lines).rstrip() + "\n", bad


def write_index(root: str | Path, coverage: str | None = None) -> tuple[Path, list[str]]:
    """Write ``root/README.md`` (atomically); return its path and the unreadable tables."""
    text, bad = render_index(root, coverage)
    path = Path(root) / INDEX_FILE
    write_text_atomic(text, path)
    return path, bad


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
