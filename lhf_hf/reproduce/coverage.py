"""Coverage: every cell of every shipped spec at one preset, measured or not, and what is left.

``results/README.md`` lists the tables that exist; this says which cells of the paper's tables they
cover at a preset's *current* budget, and for the rest why not and what it would take.  Per shipped
spec that has the preset, per env of the preset's grid and per backbone, a cell is:

- **done**: a table under the root (its ``results.json``) holds it from at least the preset's
  number of runs, and its recorded settings (collect, filter, train, evaluate) equal the spec's
  now.  A preset's budget changes (the cpu presets went from 50 to 100 histories per goal), so a
  table made by the same command line before that is
- **older budget**: named with the settings that differ; or the cell is
- **not run**.

Cells not done get the estimated wall time of what is left of them (``estimate.py``, ``--jobs 2``,
the shipped reference rates of the first machine in ``rates.json``, so the page does not change
with the machine that renders it).  "Left" counts a committed export's evaluations
(``ROOT/stages/*``, ``portable.py``) as done, with the trainings only they needed, the way
``--import-stages`` would.  Each cell is estimated alone: a stage two cells share (a collection, the
sweeps' common baseline) is counted in each.

The envs of the spec's grid that the preset leaves out (the cpu presets keep Darkroom: the other
gridworlds need context 200, Meta-World a GPU) get one line each, with the estimate of all their
backbones from scratch: the stated reason and the cost of the cells that did not fit.

Config equality is checked on the recorded settings, not on the stage hashes: a table made before
a default changed inside a config class still counts as the current budget.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from urllib.parse import quote

import yaml

from .estimate import REFERENCE, duration, estimate, load_reference, reference_machines
from .experiment import Experiment, experiment_names, load_experiment, spec_path, train_settings
from .report import _objective, _pct
from .reproduce import plan_stages
from .stages import needed_stages

#: The recorded settings a table must share with the spec to count as its current budget.
SETTINGS = ("collect", "filter", "train", "evaluate")
#: ``--jobs`` the estimates assume (2 cores: two single-thread stages at once).
JOBS = 2


def _flat(d, prefix: str = "") -> dict[str, object]:
    """``{"collect.histories": 100, "train.by_objective.dicp.max_steps": 4000, ...}``."""
    if not isinstance(d, dict):
        return {prefix: d}
    out: dict[str, object] = {}
    for k, v in d.items():
        out.update(_flat(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def differences(recorded: dict, current: Experiment, objective: str) -> list[str]:
    """The settings one backbone's cells of a table were made with (its recorded experiment) that
    differ from the spec's now, as ``"collect.histories 50 (now 100)"``; empty when it is the
    current budget.  Training compares the backbone's own settings (``train_settings``: the shared
    ones and its ``by_objective`` overrides), so a change of AD's steps does not date a DICP cell."""
    now = current.to_dict()

    def settings(exp: dict) -> dict:
        out = {k: exp.get(k) or {} for k in SETTINGS}
        out["train"] = train_settings(out["train"], objective)
        return _flat(out)

    old, new = settings(recorded), settings(now)
    return [
        f"{k} {old.get(k, 'unset')} (now {new.get(k, 'unset')})"
        for k in sorted(set(old) | set(new))
        if old.get(k) != new.get(k)
    ]


def _tables(root: Path) -> list[tuple[Path, dict]]:
    out = []
    for path in sorted(root.glob("*/results.json")):
        try:
            summary = json.loads(path.read_text())
            summary["experiment"]["name"]  # noqa: B018 (a table without it is not ours)
        except (OSError, ValueError, KeyError, TypeError):
            continue  # the index names unreadable tables itself
        out.append((path.parent, summary))
    return out


def exported_hashes(root: Path) -> dict[str, str]:
    """``{stage hash: export folder name}`` of every evaluation in ``ROOT/stages/*/stages.json``
    (checked by ``lhf verify``/``--import-stages``; here only read)."""
    out = {}
    for index in sorted((root / "stages").glob("*/stages.json")):
        try:
            stages = json.loads(index.read_text())["stages"]
            out.update({s["hash"]: index.parent.name for s in stages if s["kind"] == "evaluate"})
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return out


def _reference() -> dict:
    """The first shipped machine's rates (its CPU named in the page), whichever machine renders."""
    data = json.loads(REFERENCE.read_text()) if REFERENCE.exists() else {}
    first = (reference_machines(data) or [{}])[0]
    return load_reference(cpu=first.get("cpu", "?"), isa=first.get("isa", "?"))


def _left(exp: Experiment, root: Path, exported: dict[str, str], reference: dict) -> dict:
    """What is left of ``exp``'s plan once the committed exports count as done: the estimated wall
    time (``None`` when some stage was never measured: then ``at_least``), and the runs whose
    evaluations are all exported."""
    nowhere = root / ".coverage-nothing-is-cached-here"
    stages, evals = plan_stages(exp, nowhere)
    targets = [s for group in evals.values() for s in group]
    left = [
        s
        for s in needed_stages(stages, nowhere, targets, done=lambda s: s.hash in exported)
        if s.hash not in exported
    ]
    est = estimate(left, nowhere, JOBS, reference)
    runs: dict[int, list[bool]] = {}
    for s in stages:
        if s.kind == "evaluate":
            # an evaluation's seed is its run (``Experiment.eval_config``)
            runs.setdefault(int(s.config["seed"]), []).append(s.hash in exported)
    return {
        "wall_s": est["wall_s"],
        "missing": est["missing"],
        "exported_runs": sorted(r for r, flags in runs.items() if all(flags)),
        "exports": sorted({exported[s.hash] for s in stages if s.hash in exported}),
    }


def _spec_envs(name: str) -> list[str]:
    """The spec's whole grid of envs (its top level), which a preset may narrow."""
    spec = yaml.safe_load(spec_path(name).read_text()) or {}
    return list(spec.get("envs") or [])


def cell_results(summary: dict, env: str, objective: str) -> list[dict]:
    """A table's rows of one env and backbone, each with its arm (one per sweep value)."""
    return [
        {**row, "arm": cell["arm"]}
        for cell in summary.get("cells") or []
        if cell.get("env_id") == env
        for row in cell.get("rows") or []
        if _objective(row.get("backbone", "?")) == objective
    ]


def coverage(root: str | Path, preset: str = "cpu", names: list[str] | None = None) -> list[dict]:
    """One entry per shipped spec with ``preset`` (or ``names``): its cells (env x backbone, the
    preset's envs) with their status, and the envs of its grid outside the preset."""
    root = Path(root)
    tables = _tables(root)
    exported = exported_hashes(root)
    reference = _reference()
    out = []
    for name in names or experiment_names():
        try:
            exp = load_experiment(name, preset)
        except ValueError:
            continue  # no such preset
        mine = [
            (folder, s)
            for folder, s in tables
            if s["experiment"]["name"] == name and s["experiment"].get("preset") == preset
        ]
        cells = []
        for env in exp.envs:
            for obj in exp.objectives:
                cell = {"env": env, "objective": obj, "paper": (exp.paper.get(env) or {}).get(obj)}
                found = []  # (current?, created, folder, summary, differences)
                for folder, s in mine:
                    rows = cell_results(s, env, obj)
                    if not rows or int(s["experiment"].get("runs") or 0) < exp.runs:
                        continue
                    diff = differences(s["experiment"], exp, obj)
                    found.append((not diff, str(s.get("created", "")), folder, s, rows, diff))
                if found:
                    current, _, folder, s, rows, diff = max(found, key=lambda f: f[:2])
                    cell.update(
                        status="done" if current else "older budget",
                        table=folder.name,
                        stage_s=s.get("stage_s"),
                        rows=rows,
                        differences=diff,
                    )
                else:
                    cell.update(status="not run")
                if cell["status"] != "done":
                    one = dataclasses.replace(exp, envs=(env,), objectives=(obj,), narrowed=True)
                    cell["left"] = _left(one, root, exported, reference)
                cells.append(cell)
        outside = []
        for env in _spec_envs(name):
            if env in exp.envs:
                continue
            one = dataclasses.replace(exp, envs=(env,))
            outside.append({"env": env, "left": _left(one, root, exported, reference)})
        out.append({"experiment": exp, "cells": cells, "outside": outside})
    return out


def _estimate(left: dict) -> str:
    text = f"~{duration(left['wall_s'])}"
    if left["missing"]:  # "collect|metaworld-push|sb3|sac" -> "collect on metaworld-push"
        kinds = sorted({" on ".join(k.split("|")[:2]) for k in left["missing"]})
        never = f"stages never measured ({', '.join(kinds)})"
        # what was measured is only a start-up or a filter: the cell's cost is unknown
        text = f"unknown: {never}" if left["wall_s"] < 60 else f">= {text} + {never}"
    if left["exported_runs"]:
        runs = ", ".join(map(str, left["exported_runs"]))
        text += f"; run {runs} exported in {', '.join(left['exports'])}"
    return text


def _ours(rows: list[dict]) -> str:
    parts = []
    for r in rows:
        e = r.get("E")
        e = None if e is None or not math.isfinite(float(e)) else float(e)
        label = r["backbone"] + ("" if r["arm"] == "lhf" else f" {r['arm']}")
        parts.append(f"{label} {_pct(e)}")
    return ", ".join(parts)


def render_coverage(entries: list[dict], preset: str) -> list[str]:
    """The coverage section of ``results/README.md`` (markdown lines)."""
    ref = _reference().get("cpu", "?")
    lines = [
        f"## Coverage at the {preset} preset",
        "",
        f"Every cell of every shipped spec at `--preset {preset}` (`lhf_hf/reproduce/coverage.py`): "
        "**done** when a table here holds it from the preset's runs at the spec's current "
        "settings; **older budget** when the tables that hold it were made at other settings "
        "(which are named). Left to run: the estimated wall time at `--jobs 2` from the reference "
        f"rates ({ref}; an AVX2 AMD EPYC takes up to ~2x), less the evaluations committed under "
        "`stages/` (`--import-stages`); each cell alone, so a stage shared by two cells is counted "
        "in each.",
        "",
        "| spec | env | backbone | paper E (%) | status | ours: E (%) | table (stage time) | left to run |",
        "|---|---|---|---|---|---|---|---|",
    ]
    done = total = 0
    left_s = 0.0
    for entry in entries:
        exp = entry["experiment"]
        for c in entry["cells"]:
            total += 1
            paper = "-" if c["paper"] is None else f"{float(c['paper']):+.1f}"
            table = ours = "-"
            if "table" in c:
                hours = c.get("stage_s")
                table = f"[{c['table']}]({quote(c['table'])}/report.md)" + (
                    f" ({float(hours) / 3600:.2f} h)" if hours else ""
                )
                ours = _ours(c["rows"])
            status = c["status"]
            if status == "older budget":
                status += ": " + "; ".join(c["differences"])
            if c["status"] == "done":
                done += 1
                left = "-"
            else:
                left = _estimate(c["left"])
                left_s += c["left"]["wall_s"]
            lines.append(
                f"| {exp.name} | {c['env']} | {c['objective'].upper()} | {paper} | {status} "
                f"| {ours} | {table} | {left} |"
            )
    lines += [
        "",
        f"{done} of {total} cells done at the {preset} preset's current budget; the other "
        f"{total - done}: ~{duration(left_s)} wall at `--jobs 2`, each cell alone.",
        "",
    ]
    outside = [(e["experiment"], o) for e in entries for o in e["outside"]]
    if outside:
        lines += [
            f"Envs of the specs' grids that the {preset} preset leaves out (all their backbones, "
            "from scratch, `--jobs 2`; each spec's budget says why):",
            "",
        ]
        lines += [f"- {exp.name}: {o['env']}, {_estimate(o['left'])}" for exp, o in outside]
        lines.append("")
    return lines
