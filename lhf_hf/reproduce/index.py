"""``results/README.md``: every reproduced table in one place, our E beside the paper's, cell by cell.

Reads the ``results.json`` of every report folder under a root (``lhf reproduce`` writes one per
table) and renders, per table: the command and budget, then one row per env x arm x backbone with
our E (+/- its std over paired runs, and its 95 % confidence interval), the paper's E, the verdict
(``report.verdict``) and the whole-curve returns without and with LHF; and the stage time the table
took.  A table whose ``results.json`` cannot be read is listed with the reason, not skipped silently.
"""

from __future__ import annotations

import json
from pathlib import Path

from .report import _objective, _pct, verdict

INDEX_FILE = "README.md"


def _ci(row: dict) -> str:
    ci = row.get("E_ci95")
    return f"{_pct(ci[0])} .. {_pct(ci[1])}" if ci else "-"


def _table(folder: Path, summary: dict) -> list[str]:
    exp = summary["experiment"]
    paper = exp.get("paper") or {}
    hours = summary.get("stage_s")
    lines = [
        f"## [{exp.get('title', exp['name'])}]({folder.name}/report.md)",
        "",
        f"`lhf reproduce {exp['name']} --preset {exp['preset']} --runs {exp['runs']}`"
        + (f"; {hours / 3600:.2f} h of stage time" if hours else "")
        + f"; {summary.get('created', '?')}.",
        "",
        "| env | backbone | E (%) ± std | 95% CI | paper E (%) | verdict | return without -> with LHF |",
        "|---|---|---|---|---|---|---|",
    ]
    for cell in summary["cells"]:
        label = cell["env_id"] + ("" if cell["arm"] == "lhf" else f" ({cell['arm']})")
        for r in cell["rows"]:
            p = (paper.get(cell["env_id"]) or {}).get(_objective(r["backbone"]))
            std = f" ± {100 * r['E_std']:.1f}" if r.get("E_std") is not None else ""
            cell_verdict = verdict(r["E"], r.get("E_std")).replace("|", "\\|")  # a table cell
            lines.append(
                f"| {label} | {r['backbone']} | {_pct(r['E'])}{std} | {_ci(r)} | "
                f"{'-' if p is None else f'{p:+.1f}'} | {cell_verdict} | "
                f"{r['baseline_mean']:.2f} -> {r['lhf_mean']:.2f} |"
            )
    return lines + [""]


def render_index(root: str | Path) -> str:
    """The index of every ``*/results.json`` under ``root`` (one table each), as markdown."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"no results folder {root}")
    folders = sorted(p.parent for p in root.glob("*/results.json"))
    lines = [
        "# Reproduced tables",
        "",
        "Every table `lhf reproduce` wrote under this folder (`scripts/results_index.py` renders this "
        "page from their `results.json`). E = (whole-curve mean return with LHF - without) / without, "
        "averaged over paired runs; ± is its std over the runs, the interval the 95% confidence "
        "interval of the mean (Student t). The verdict counts an effect only when |E| exceeds its std.",
        "",
    ]
    if not folders:
        lines.append(f"No tables yet: `lhf reproduce EXPERIMENT --out {root}/NAME` writes one.")
    for folder in folders:
        try:
            lines += _table(folder, json.loads((folder / "results.json").read_text()))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            lines += [f"## {folder.name}", "", f"`results.json` unreadable: {exc!r}", ""]
    return "\n".join(lines).rstrip() + "\n"


def write_index(root: str | Path) -> Path:
    """Write ``root/README.md`` (atomically) and return its path."""
    from lhf_hf.utils.io import write_text_atomic

    path = Path(root) / INDEX_FILE
    write_text_atomic(render_index(root), path)
    return path
