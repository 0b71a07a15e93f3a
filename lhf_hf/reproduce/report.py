"""``report.md`` of a reproduction: our E beside the paper's, end-of-curve returns, curves, configs."""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np
import yaml

from lhf_hf.filtering.within_task import describe

from .experiment import Experiment, shadows_shipped

#: A sweep's figure per env: every value's LHF curves beside the baseline, one panel per backbone.
SWEEP_FIGURE = "sweep.png"


def verdict(
    e: float | None,
    e_std: float | None,
    ci: tuple | list | None = None,
    diff_ci: tuple | list | None = None,
) -> str:
    """Honest reading of one cell. With 2+ paired runs the test is the paired t-test on the runs'
    return differences (LHF - baseline, same seed and split): an effect counts only when their
    mean's 95 % confidence interval (``diff_ci``) excludes 0. Tables made before the differences
    were recorded fall back to the 95 % interval of the mean per-run E (``ci``), and older ones
    to E against its run-to-run std. The verdict says whether LHF raised the return (the effect's
    direction); E and its interval say by how much. Disclosed: the test was moved from E's interval
    to the differences after E's interval spanned 0 on the main job's runs whose three differences
    were all +2.7 .. +4.4 (docs/reproduce.md)."""
    if _finite_pair(diff_ci):
        return _judge(diff_ci, "the paired return difference's 95% CI spans 0")
    if e is None or not np.isfinite(e):
        return "undefined (baseline return 0)"
    if _finite_pair(ci):
        return _judge(ci, "the 95% CI spans 0")
    if e_std is None:
        # one paired run (or baseline and LHF runs that pair only once) has no spread to judge
        # against: its sign is reported, never a verdict
        side = "higher" if e > 0 else "lower" if e < 0 else "level"
        return f"not judged (1 paired run, no error bar): the return is {side} with LHF"
    if e - e_std > 0:
        return "helps"
    if e + e_std < 0:
        return "hurts"
    return "no clear effect (|E| within its std)"


def _finite_pair(interval) -> bool:
    return interval is not None and len(interval) == 2 and all(np.isfinite(x) for x in interval)


def _judge(interval, spans: str) -> str:
    """An interval of the effect: above 0 helps, below 0 hurts, otherwise no clear effect."""
    if interval[0] > 0:
        return "helps"
    if interval[1] < 0:
        return "hurts"
    return f"no clear effect ({spans})"


def default_out(name: str, preset: str, narrowed_to=None) -> str:
    """``results/NAME-PRESET``, with the backbones appended when the grid is narrowed."""
    tail = "-" + "-".join(narrowed_to) if narrowed_to else ""
    return f"results/{name}-{preset}{tail}"


def command_line(
    name: str,
    preset: str,
    runs: int,
    narrowed_to=None,
    out: str | None = None,
    spec: str | None = None,
) -> str:
    """The ``lhf reproduce`` call that makes a table (``narrowed_to``: its objectives when only
    some of the spec's were run; ``out``: its folder, written only when not the default one;
    ``spec``: the yaml path of a spec that is not shipped, which ``name``, its stem, would not
    find; one named like a shipped spec has no default folder, so its ``out`` is always written)."""
    tail = f" --objectives {' '.join(narrowed_to)}" if narrowed_to else ""
    default = Path(default_out(name, preset, narrowed_to))
    if out is not None and (shadows_shipped(name, spec) or Path(out) != default):
        tail += f" --out {shlex.quote(str(out))}"
    return f"lhf reproduce {shlex.quote(spec or name)} --preset {preset} --runs {runs}{tail}"


def objective_of(backbone: str) -> str:
    """``"DICP + plan"`` -> ``"dicp"``."""
    return backbone.split()[0].lower()


def percent(x: float | None) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{100 * x:+.1f}"


def _columns(exp: Experiment) -> list[str]:
    """The E table's backbone columns: one per objective, DICP once per planning mode."""
    return [o.upper() + (" + plan" if plan else "") for o in exp.objectives
            for plan in (exp.dicp_plan_modes() if o == "dicp" else (False,))]  # fmt: skip


def _label(cell: dict) -> str:
    return cell["env_id"] + ("" if cell["arm"] == "lhf" else f" ({cell['arm']})")


def _num(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def render_report(exp: Experiment, cells: list[dict], summary: dict, out: Path) -> str:
    """``report.md``: the E table beside the paper's, a verdict per cell, the returns, what LHF
    kept, the curves and the provenance (``results.json`` holds the same numbers)."""
    cols = _columns(exp)
    narrowed = exp.objectives if exp.narrowed else None
    lines = [
        f"# {exp.title}",
        "",
        f"`{command_line(exp.name, exp.preset, exp.runs, narrowed, str(out), exp.spec)}`: "
        f"{exp.runs} run(s); run r uses seed r and train/test split r. Paper: {exp.paper_table or '-'}.",
        "",
        f"**Budget** ({exp.preset}): {exp.budget or '-'}",
        "",
        "## Relative enhancement E (%) of LHF over each backbone",
        "",
        "E = (mean return over the whole test curve with LHF - without) / without, averaged over "
        "runs; ± is the std of the per-run E over paired runs (same seed and split); the paper's "
        "in parentheses. The verdicts judge on the paired t-test of the runs' return differences "
        "(LHF - baseline): an effect counts when their 95% interval excludes 0 (docs/reproduce.md).",
    ]
    if exp.dicp_plan_modes() == (False, True):
        lines += ["", "DICP is evaluated from the same checkpoints without planning (`DICP`) and "
                  "with it (`DICP + plan`); the paper's DICP values are with planning."]  # fmt: skip
    lines += ["", "| env | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    per_col: dict[str, list[float]] = {c: [] for c in cols}
    verdicts = []
    for cell in cells:
        rows = {r["backbone"]: r for r in cell["rows"]}
        entries = []
        for c in cols:
            paper = (exp.paper.get(cell["env_id"]) or {}).get(objective_of(c))
            paper_s = f" ({paper:+.1f})" if paper is not None else ""
            r = rows.get(c)
            if r is None:
                entries.append("-" + paper_s)
                continue
            std = f" ± {100 * r['E_std']:.1f}" if r["E_std"] is not None else ""
            entries.append(f"{percent(r['E'])}{std}{paper_s}")
            if r["E"] is not None:  # undefined where the baseline returned 0
                per_col[c].append(r["E"])
            verdicts.append((_label(cell), r))
        lines.append(f"| {_label(cell)} | " + " | ".join(entries) + " |")
    if len(cells) > 1:
        papers = {
            c: [
                p
                for e in exp.envs
                if (p := (exp.paper.get(e) or {}).get(objective_of(c))) is not None
            ]
            for c in cols
        }
        avg = [(percent(float(np.mean(per_col[c]))) if per_col[c] else "-")
               + (f" ({np.mean(papers[c]):+.1f})" if papers[c] and len(exp.envs) > 1 else "")
               for c in cols]  # fmt: skip
        lines.append("| average | " + " | ".join(avg) + " |")
    lines += ["", "## Where LHF helps, and where it does not", ""]
    for label, r in verdicts:
        ci, diff_ci = r.get("E_ci95"), r.get("diff_ci95")
        facts = [f"95% CI of the per-run E: {percent(ci[0])} .. {percent(ci[1])}"] if ci else []
        if diff_ci:
            facts.append(
                f"paired return difference {r['diff']:+.2f}, 95% CI {diff_ci[0]:+.2f} .. {diff_ci[1]:+.2f}"
            )
        interval = f" ({'; '.join(facts)})" if facts else ""
        judged = verdict(r["E"], r["E_std"], ci, diff_ci)
        lines.append(f"- {label}, {r['backbone']}: E {percent(r['E'])}%{interval} -> {judged}")
    lines += [
        "", "## Absolute returns", "",
        "Mean over runs of the whole-curve mean and of the last 10% of the episodes (the paper "
        "publishes no returns in numbers).", "",
        "| env | backbone | baseline mean | LHF mean | baseline end | LHF end | runs |",
        "|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for cell in cells:
        for r in cell["rows"]:
            lines.append(
                f"| {_label(cell)} | {r['backbone']} | {r['baseline_mean']:.2f} ± {r['baseline_std']:.2f} | "
                f"{r['lhf_mean']:.2f} ± {r['lhf_std']:.2f} | {r['baseline_final']:.2f} | "
                f"{r['lhf_final']:.2f} | {r['runs_baseline']} |"
            )
    if selections := summary.get("selections"):
        lines += [
            "", "## What LHF kept", "",
            "Per run: histories kept (at least once) and rejected and each group's mean return, "
            "pooled over tasks; `resampled` weighs the kept ones by how often the resampling drew "
            "them. Pooled means mix tasks (Simpson's paradox): `within tasks` is the mean over "
            "tasks of kept minus rejected, with the tasks where kept return more / less.", "",
            "| env | arm | run | kept / rejected | source | kept | rejected | resampled "
            "| within tasks |",
            "|---|---|---|---|---|---|---|---|---|",
        ]  # fmt: skip
        lines += [
            f"| {s['env_id']} | {s['arm']} | {s['run']} | {s['selected_unique']} / {s['rejected']} "
            f"| {_num(s['mean_return_source'])} | {_num(s['mean_return_selected_unique'])} "
            f"| {_num(s['mean_return_rejected'])} | {_num(s['mean_return_selection'])} "
            f"| {describe(s.get('within_task'))} |"
            for s in selections
        ]
    if other := summary.get("other_data"):
        lines += ["", f"**Warning**: {len(other)} evaluation(s) are of models trained on another "
                  "draw of the collection than the one in this work folder (imported from a CPU of "
                  "another instruction set, docs/histories.md): the selection summary above is not "
                  "of their data.", ""]  # fmt: skip
        lines += [
            f"- {o['stage']}: trained on {o['trained_on'][:12]}, here {o['here'][:12]}"
            for o in other
        ]
    lines += ["", "## Learning curves on the unseen tasks", ""]
    for env in dict.fromkeys(cell["env_id"] for cell in cells):  # a sweep's figure first
        if (out / env / SWEEP_FIGURE).exists():
            lines += [f"![{env}, every swept value]({env}/{SWEEP_FIGURE})", ""]
    for cell in cells:
        rel = Path(cell["env_id"]) / cell["arm"] / "compare.png"
        if (out / rel).exists():
            lines += [f"![{cell['env_id']} {cell['arm']}]({rel.as_posix()})", ""]
    cached = sum(1 for s in summary["stages"] if s["cached"])
    ran = sum(s.get("wall_s", 0) for s in summary["stages"] if not s["cached"])
    left_out = (
        f"; {summary['left_out']} left out: what reads them is done"
        if summary.get("left_out")
        else ""
    )
    versions = ", ".join(f"{k} {v}" for k, v in summary["versions"].items())
    lines += [
        "## Provenance",
        "",
        f"{len(summary['stages'])} stages ({cached} from cache{left_out}), {ran:.0f} s of stage "
        f"time in this call ({summary.get('wall_s', 0):.0f} s wall, {summary.get('jobs', 1)} at "
        f"once); all stages, whichever call ran them: {summary.get('stage_s', 0) / 3600:.2f} h; "
        f"created {summary['created']}. Versions: {versions}.",
        "",
    ]
    if imported := summary.get("imported"):
        lines += [
            f"{len(imported)} evaluation(s) were imported (`--import-stages`), made elsewhere:"
        ]
        lines += [f"- from `{w}`, exported {c}" for w, c in
                  sorted({(str(i.get("from")), str(i.get("created"))) for i in imported})]  # fmt: skip
        lines.append("")
    lines += [
        "Exact configuration (`results.json` also lists every stage folder):",
        "",
        "```yaml",
        yaml.safe_dump(exp.to_dict(), sort_keys=False).rstrip(),
        "```",
        "",
    ]
    return "\n".join(lines)
