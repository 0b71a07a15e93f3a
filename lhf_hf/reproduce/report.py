"""``report.md`` of a reproduction (docs/reproduce.md, ``report.py``): our E beside the paper's, a
verdict per cell, the returns, what LHF kept, the curves and the provenance."""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np
import yaml

from lhf_hf.envs import get_spec
from lhf_hf.filtering.within_task import describe

from .experiment import Experiment, shadows_shipped

#: A sweep's figure per env: every value's LHF curves beside the baseline, one panel per backbone.
SWEEP_FIGURE = "sweep.png"
#: The mean returns of a selection's summary in the report's columns: the source, the histories
#: kept and rejected, and the kept ones weighted by how often the resampling drew them.
MEANS = ("source", "selected_unique", "rejected", "selection")


def judge(interval, spans: str) -> str:
    """An interval of the effect: above 0 helps, below 0 hurts, otherwise no clear effect."""
    if interval[0] > 0:
        return "helps"
    if interval[1] < 0:
        return "hurts"
    return f"no clear effect ({spans})"


def verdict(row: dict) -> str:
    """One cell's reading from its ``evaluation.compare`` row: with 2+ paired runs the paired
    t-test on the runs' return differences (LHF - baseline, same seed and split) decides, not E's
    interval (a per-run E divides by its run's baseline return: docs/reproduce.md says why)."""
    ci = row.get("diff_ci95")
    if ci is not None and all(np.isfinite(x) for x in ci):
        return judge(ci, "the paired return difference's 95% CI spans 0")
    e = row.get("E")
    if e is None or not np.isfinite(e):
        return "undefined (baseline return 0)"
    # one paired run (or runs that pair only once) has no spread to judge against: its sign
    side = "higher" if e > 0 else "lower" if e < 0 else "level"
    return f"not judged (1 paired run, no error bar): the return is {side} with LHF"


def default_out(name: str, preset: str, narrowed_to=None) -> str:
    """``results/NAME-PRESET``, with the backbones appended when the grid is narrowed."""
    tail = "-" + "-".join(narrowed_to) if narrowed_to else ""
    return f"results/{name}-{preset}{tail}"


def command_line(name, preset, runs=None, narrowed_to=None, out=None, spec=None) -> str:
    """The ``lhf reproduce`` call that makes a table: ``spec`` (the yaml path of a spec that is not
    shipped, else ``name``), ``--runs`` when given, ``--objectives`` when narrowed, ``--out`` when
    it is not the default folder (always for a spec named like a shipped one: it has none)."""
    tail = "" if runs is None else f" --runs {runs}"
    tail += f" --objectives {' '.join(narrowed_to)}" if narrowed_to else ""
    default = Path(default_out(name, preset, narrowed_to))
    if out is not None and (shadows_shipped(name, spec) or Path(out) != default):
        tail += f" --out {shlex.quote(str(out))}"
    return f"lhf reproduce {shlex.quote(spec or name)} --preset {preset}{tail}"


def objective_of(backbone: str) -> str:
    """``"DICP + plan"`` -> ``"dicp"``."""
    return backbone.split()[0].lower()


def percent(x: float | None) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{100 * x:+.1f}"


def columns(exp: Experiment) -> list[str]:
    """The E table's backbone columns: one per objective, DICP once per planning mode."""
    modes = {o: exp.dicp_plan_modes() if o == "dicp" else ("none",) for o in exp.objectives}
    return [exp.column(o, plan) for o in exp.objectives for plan in modes[o]]


def readings(exp: Experiment, cells: list[dict]) -> list[dict]:
    """Per cell and E-table column: the cell's ``label``, the ``column``, the paper's E in percent
    (``paper``) and, where the cell has that backbone, its compare ``row`` and ``verdict``."""
    out = []
    # the paper's DICP values are with the reference planner: beside that column only, where the
    # table has it (its other DICP columns are ours or the policy alone)
    planned = "dicp" in exp.objectives and "plan" in exp.dicp_plan_modes()
    reference = exp.column("dicp", "plan") if planned else None
    for cell in cells:
        rows = {r["backbone"]: r for r in cell["rows"]}
        for column in columns(exp):
            paper = (exp.paper.get(cell["env_id"]) or {}).get(objective_of(column))
            if objective_of(column) == "dicp" and column != reference:
                paper = None  # the policy alone, or a variant: not what the paper measured
            row = rows.get(column)
            found = {"label": _label(cell), "column": column, "paper": paper, "row": row}
            out.append({**found, "verdict": None if row is None else verdict(row)})
    return out


def _dicp_model(exp: Experiment) -> str:
    """What the DICP model is, beside the reference code's (issue 55: no unlabelled departure)."""
    encoding = exp.train_config("dicp", 0, dataset="-", selection=None, out="-").state_encoding
    if not any(np.issubdtype(get_spec(env).state_space.dtype, np.integer) for env in exp.envs):
        states = "real-valued states as the env gives them"  # no encoding to choose
    else:
        # the reference embeds a context transition's states as raw (row, col) numbers, the query
        # state by its cell, and predicts the next state's cell (jaehyeon-son/dicp, model/ad.py)
        states = (
            "states one-hot over the grid's cells (ours; the reference embeds context states as "
            "raw coordinates and only the query state and the next-state head by cell)"
            if encoding == "cells"
            else f"{encoding} states one-hot per coordinate (ours; the reference embeds context "
            "states as raw coordinates and the query state and the next-state head by cell)"
        )
    where = (
        "the paper's DICP E stands beside the reference planner on this model, the closest cell, "
        "not the reference model itself"
        if "plan" in exp.dicp_plan_modes()
        else "this table does not plan, so the paper's DICP E (with planning) has no cell here"
    )
    return (
        "The DICP model is the LHF paper's objective (action, reward, next-state and "
        "return-to-go labels at every position, a query-action token after each transition; the "
        f"reference code labels one query per window and has no return head) on {states}: "
        f"{where} (the spec's choices say how each setting was chosen)."
    )


def _label(cell: dict) -> str:
    return cell["env_id"] + ("" if cell["arm"] == "lhf" else f" ({cell['arm']})")


def _num(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def _table(header: list[str], rows: list[list]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(str(x) for x in row) + " |" for row in rows]


def _entry(r: dict) -> str:
    """An E-table entry: ours +/- its std, the paper's in parentheses."""
    paper = "" if r["paper"] is None else f" ({r['paper']:+.1f})"
    if r["row"] is None:
        return "-" + paper
    std = r["row"]["E_std"]
    return percent(r["row"]["E"]) + ("" if std is None else f" ± {100 * std:.1f}") + paper


def _average(exp: Experiment, column: str, found: list[dict]) -> str:
    ours = [r["row"]["E"] for r in found if r["column"] == column and r["row"]]
    ours = [e for e in ours if e is not None]  # undefined where the baseline returned 0
    papers = [(exp.paper.get(e) or {}).get(objective_of(column)) for e in exp.envs]
    papers = [p for p in papers if p is not None]
    paper = f" ({np.mean(papers):+.1f})" if papers and len(exp.envs) > 1 else ""
    return (percent(float(np.mean(ours))) if ours else "-") + paper


def _choices(exp: Experiment) -> list[str]:
    """How the spec's named settings were chosen (``Experiment.choices``)."""
    if not exp.choices:
        return []

    def cell(x) -> str:  # a pipe would end the table's cell
        return str(x).replace("|", "\\|")

    rows = [[f"`{k}`", f"`{cell(exp.setting(k))}`", f"**{c['chosen']}**" if c["chosen"] == "test"
             else c["chosen"], cell(c["evidence"])] for k, c in exp.choices.items()]  # fmt: skip
    legend = ("validation: on validation goals (train goals held out of the tuning runs' data, "
              "a test goal of no split 0-9; evidence that says 'earlier validation goals' was "
              "made on an earlier set, some of them test goals of other splits: "
              "results/FINDINGS.md); "
              "paper / reference: the paper's or the reference code's value; budget: by cost, not "
              "by return; design: measured elsewhere; **test**: on test goals, to be discounted")  # fmt: skip
    return ["", f"**How the settings were chosen** ({legend}):", "",
            *_table(["setting", "value", "chosen", "evidence"], rows)]  # fmt: skip


def _reading(r: dict) -> str:
    """A verdict line: E, the intervals it rests on, the verdict."""
    row, facts = r["row"], []
    if ci := row.get("E_interval95"):
        facts.append(f"95% interval of E: {percent(ci[0])} .. {percent(ci[1])}")
    elif ci := row.get("E_ci95"):  # a comparison that recorded the per-run E's interval instead
        facts.append(f"95% CI of the per-run E: {percent(ci[0])} .. {percent(ci[1])}")
    if ci := row.get("diff_ci95"):
        facts.append(
            f"paired return difference {row['diff']:+.2f}, 95% CI {ci[0]:+.2f} .. {ci[1]:+.2f}"
        )
    interval = f" ({'; '.join(facts)})" if facts else ""
    return f"- {r['label']}, {r['column']}: E {percent(row['E'])}%{interval} -> {r['verdict']}"


def render_report(exp: Experiment, cells: list[dict], summary: dict, out: Path) -> str:
    """``report.md``: the E table beside the paper's, a verdict per cell, the returns, what LHF
    kept, the curves and the provenance (``results.json`` holds the same numbers)."""
    found = readings(exp, cells)
    narrowed = exp.objectives if exp.narrowed else None
    command = command_line(exp.name, exp.preset, exp.runs, narrowed, str(out), exp.spec)
    lines = [
        f"# {exp.title}",
        "",
        f"`{command}`: {exp.runs} run(s); run r uses seed r and train/test split r. "
        f"Paper: {exp.paper_table or '-'}.",
        "",
        f"**Budget** ({exp.preset}): {exp.budget or '-'}",
        *_choices(exp),
        "",
        "## Relative enhancement E (%) of LHF over each backbone",
        "",
        "E = (whole-curve mean return with LHF - without) / without, the returns averaged over "
        "the runs; ± is the sample std of the per-run E over paired runs (same seed and split); the paper's "
        "in parentheses. The verdicts judge on the paired t-test of the runs' return differences "
        "(LHF - baseline): an effect counts when their 95% interval excludes 0 (docs/reproduce.md).",
    ]
    if len(exp.dicp_plan_modes()) > 1:
        named = ", ".join(f"`{exp.column('dicp', m)}`" for m in exp.dicp_plan_modes())
        lines += ["", f"DICP is evaluated from the same checkpoints as {named}: `DICP + plan` is "
                  "the reference planner (every step once the context is full), a suffix names "
                  "a variant of ours; the paper's DICP values are with planning."]  # fmt: skip
    if "dicp" in exp.objectives:
        lines += ["", _dicp_model(exp)]
    by_label: dict[str, list[str]] = {}
    for r in found:
        by_label.setdefault(r["label"], []).append(_entry(r))
    e_rows = [[label, *entries] for label, entries in by_label.items()]
    if len(cells) > 1:
        e_rows.append(["average", *(_average(exp, c, found) for c in columns(exp))])
    lines += ["", *_table(["env", *columns(exp)], e_rows)]
    lines += ["", "## Where LHF helps, and where it does not", ""]
    lines += [_reading(r) for r in found if r["row"] is not None]
    lines += [
        "", "## Absolute returns", "",
        "Mean over runs of the whole-curve mean and of the last 10% of the episodes (the paper "
        "publishes no returns in numbers).", "",
    ]  # fmt: skip
    returns = []
    for cell in cells:
        for r in cell["rows"]:
            means = [f"{r[f'{k}_mean']:.2f}" + ("" if r.get(f"{k}_std") is None else
                     f" ± {r[f'{k}_std']:.2f}") for k in ("baseline", "lhf")]  # fmt: skip
            ends = [f"{r[f'{k}_final']:.2f}" for k in ("baseline", "lhf")]
            returns.append([_label(cell), r["backbone"], *means, *ends, r["runs_baseline"]])
    header = ["env", "backbone", "baseline mean", "LHF mean", "baseline end", "LHF end", "runs"]
    lines += _table(header, returns)
    if selections := summary.get("selections"):
        lines += [
            "", "## What LHF kept", "",
            "Per run: histories kept (at least once) and rejected and each group's mean return, "
            "pooled over tasks; `resampled` weighs the kept ones by how often the resampling drew "
            "them. Pooled means mix tasks (Simpson's paradox): `within tasks` is the mean over "
            "tasks of kept minus rejected, with the tasks where kept return more / less.", "",
        ]  # fmt: skip
        kept = []
        for s in selections:
            means = [_num(s[f"mean_return_{k}"]) for k in MEANS]
            counts = f"{s['selected_unique']} / {s['rejected']}"
            kept.append(
                [s["env_id"], s["arm"], s["run"], counts, *means, describe(s.get("within_task"))]
            )
        header = ["env", "arm", "run", "kept / rejected", "source", "kept", "rejected"]
        lines += _table([*header, "resampled", "within tasks"], kept)
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
    return "\n".join(lines + _provenance(exp, summary))


def _provenance(exp: Experiment, summary: dict) -> list[str]:
    """What the table cost, which versions made it, what was imported, the exact config."""
    stages = summary["stages"]
    cached = sum(1 for s in stages if s["cached"])
    ran = sum(s.get("wall_s", 0) for s in stages if not s["cached"])
    left_out = summary.get("left_out")
    left_out = f"; {left_out} left out: what reads them is done" if left_out else ""
    versions = ", ".join(f"{k} {v}" for k, v in summary["versions"].items())
    lines = [
        "## Provenance",
        "",
        f"{len(stages)} stages ({cached} from cache{left_out}), {ran:.0f} s of stage time in this "
        f"call ({summary.get('wall_s', 0):.0f} s wall, {summary.get('jobs', 1)} at once); all "
        f"stages, whichever call ran them: {summary.get('stage_s', 0) / 3600:.2f} h; created "
        f"{summary['created']}. Versions: {versions}.",
        "",
    ]
    if imported := summary.get("imported"):
        origins = sorted({(str(i.get("from")), str(i.get("created"))) for i in imported})
        lines += [
            f"{len(imported)} evaluation(s) were imported (`--import-stages`), made elsewhere:"
        ]
        lines += [f"- from `{w}`, exported {c}" for w, c in origins] + [""]
    config = yaml.safe_dump(exp.to_dict(), sort_keys=False).rstrip()
    return lines + [
        "Exact configuration (`results.json` also lists every stage folder):",
        "",
        "```yaml",
        config,
        "```",
        "",
    ]
