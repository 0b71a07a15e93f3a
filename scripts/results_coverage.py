"""Coverage (``scripts/results_index.py --coverage``): every cell of every shipped spec at one preset, measured or not, and what is left.

``results/README.md`` lists the tables that exist; this says which cells of the paper's tables they
cover at a preset's *current* settings, and for the rest why not and what it would take.  Per
shipped spec that has the preset, per env of the preset's grid and per backbone, a cell is:

- **done**: a table under the root (its ``results.json``) holds it from at least the preset's
  number of runs, made with the settings the cell's stages run with now (``cell_settings``: the
  collection, the filter arms, the backbone's own training and its evaluations, defaults filled
  in, rebuilt from the recorded spec settings).  A preset's budget changes (the cpu presets went
  from 50 to 100 histories per goal), so a table made by the same command line before that is
- **fewer runs** or else **other settings** (named): the table that holds the cell closest to
  done (the newest among equals); or the cell is
- **not run**.

Cells not done get the estimated wall time of what is left of them (``estimate.py``, ``--jobs 2``,
the shipped reference rates of the first machine in ``rates.json``, so the page does not change
with the machine that renders it).  "Left" counts a committed export's evaluations
(``ROOT/stages/*``, ``portable.py``) as done, with the trainings only they needed, the way
``--import-stages`` would (which may also use the imported evaluations' own times as rates: the
two can differ by minutes).  Each cell is estimated alone: a stage two cells share (a collection,
the sweeps' common baseline) is counted in each.  A cell with a kind of stage never measured is
``unknown``, not a lower bound.

The envs of the spec's grid that the preset leaves out (the cpu presets keep Darkroom: the other
gridworlds need context 200; Meta-World's specs keep one or two envs) get one line each, with the
estimate of all their backbones from scratch: the stated reason and the cost of what did not fit.

Settings are compared as recorded, not as stage hashes: a table made before a default changed
inside a config class still counts as the current settings.  A malformed ``results.json`` or
``stages.json`` is named and left out, never fatal.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from urllib.parse import quote

import yaml

from lhf_hf.envs import get_spec
from lhf_hf.errors import UserError
from lhf_hf.reproduce.estimate import REFERENCE, duration, estimate, reference_rates
from lhf_hf.reproduce.experiment import (
    PRESETS,
    Experiment,
    experiment_names,
    load_experiment,
    spec_path,
)
from lhf_hf.reproduce.report import objective_of, percent
from lhf_hf.reproduce.reproduce import TRAIN_PLACES, plan_stages
from lhf_hf.reproduce.stages import needed_stages
from lhf_hf.utils.io import read_json

#: The recorded settings a table's experiment is rebuilt from (``Experiment``'s own validation).
SETTINGS = ("collect", "filter", "train", "evaluate")
#: Fields of a stage's config that place it (paths, the model it reads, resuming), not settings:
#: ``cell_settings`` builds the configs with placeholders for them (the trainings' are the ones
#: ``plan_stages`` leaves out of a stage's hash).
PLACES = (*TRAIN_PLACES, "model")
#: ``--jobs`` the estimates assume (2 cores: two single-thread stages at once).
JOBS = 2


def _flat(d, prefix: str = "") -> dict[str, object]:
    """``{"collect.histories": 100, "filter.lhf.lam": 1.0, ...}``."""
    if not isinstance(d, dict):
        return {prefix: d}
    out: dict[str, object] = {}
    for k, v in d.items():
        out.update(_flat(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def _mode_names(exp: Experiment, objective: str) -> list[str]:
    """The names a cell's evaluation modes key its settings by: ``policy``, ``plan``, ``gated``,
    ``gated:0.99``."""
    modes = exp.dicp_plan_modes() if objective == "dicp" else ("none",)
    return [{"none": "policy"}.get(m, m) for m in modes]


def cell_settings(exp: Experiment, env: str, objective: str) -> dict[str, object]:
    """Every setting the stages of one cell run with, defaults included, as flat keys: the
    collection, each filter arm, the backbone's training (``by_objective`` applied) and its
    evaluations (plan-only settings only where DICP plans).  What the stage hashes cover, less
    the upstream hashes and the run's seed and paths, so a default written out is no difference
    and a change of AD's steps or of DICP's planner does not date another backbone's cell."""
    modes = exp.dicp_plan_modes() if objective == "dicp" else ("none",)
    evaluate = {
        name: exp.eval_config(0, model="-", out="-", plan=plan).to_dict()
        for name, plan in zip(_mode_names(exp, objective), modes, strict=True)
    }
    train = exp.train_config(objective, 0, dataset="-", selection=None, out="-").to_dict()
    collect = exp.collect_config(env, 0).to_dict()
    collect.pop("split_seed", None)
    filters = {arm: f.to_dict() for arm, f in exp.filter_arms(0)}
    if not get_spec(env).is_discrete:  # the greedy search has no tie order
        for d in evaluate.values():
            d.pop("plan_ties", None)
            d.pop("plan_order", None)
    for d in (*evaluate.values(), train, collect, *filters.values()):
        d.pop("seed", None)  # the run's
        for k in PLACES:
            d.pop(k, None)
    return _flat(
        {"collect": {**collect, "half": exp.half}, "filter": filters, "train": train,
         "evaluate": evaluate}
    )  # fmt: skip


def recorded_experiment(summary: dict, current: Experiment) -> Experiment:
    """The experiment a table's ``results.json`` recorded, rebuilt on the current spec (its
    settings replaced by the recorded ones, validated as a spec is): ``ValueError`` when they are
    malformed or no longer valid."""
    rec = summary.get("experiment")
    if not isinstance(rec, dict):
        raise UserError("no recorded experiment")
    fields = {}
    for key in SETTINGS:
        value = rec.get(key) or {}
        if not isinstance(value, dict):
            raise UserError(f"experiment.{key} is a {type(value).__name__}, not a mapping")
        fields[key] = value
    if made_before(summary) and "plan_ties" not in fields["evaluate"]:
        fields["evaluate"] = {**fields["evaluate"], "plan_ties": "policy"}
    if made_before(summary, PLAN_ORDER_SINCE) and "plan_order" not in fields["evaluate"]:
        fields["evaluate"] = {**fields["evaluate"], "plan_order": "argmax"}
    runs = rec.get("runs")
    if not isinstance(runs, int) or isinstance(runs, bool):
        raise UserError(f"experiment.runs is {runs!r}, not a number of runs")
    try:
        # the current spec's account of its choices names its current settings, not the record's
        return dataclasses.replace(current, runs=runs, choices={}, **fields)
    except (TypeError, KeyError, AttributeError) as exc:  # a malformed setting's own error
        raise UserError(f"its settings cannot be rebuilt: {exc}") from None


def differences(recorded: Experiment, current: Experiment, env: str, objective: str) -> list[str]:
    """The settings one cell was made with (``recorded``) that differ from the spec's now, as
    ``"collect.histories 50 (now 100)"``; empty when it is the current budget.  A filter arm or an
    evaluation mode only one side has is one entry (``"filter.lam=2 absent (now run)"``), not one
    per field; ``tasks_per_chunk`` counts only when a spec sets it (else it follows the histories,
    ``CollectConfig``, and would name one change twice)."""
    old, new = cell_settings(recorded, env, objective), cell_settings(current, env, objective)
    if "tasks_per_chunk" not in recorded.collect and "tasks_per_chunk" not in current.collect:
        old.pop("collect.tasks_per_chunk", None)
        new.pop("collect.tasks_per_chunk", None)
    # filter arms and evaluation modes key their settings first; their names may hold dots
    # ("lam=0.5", "gated:0.99"), so a key's group is the arm or mode it starts with
    groups = {
        f"{section}.{name}"
        for exp in (recorded, current)
        for section, names in (
            ("filter", [arm for arm, _ in exp.filter_arms(0)]),
            ("evaluate", _mode_names(exp, objective)),
        )
        for name in names
    }
    out, said = [], set()
    for k in sorted(set(old) | set(new)):
        if old.get(k) == new.get(k):
            continue
        group = max((g for g in groups if k.startswith(g + ".")), key=len, default=None)
        if group is not None:
            olds = any(o.startswith(group + ".") for o in old)
            news = any(n.startswith(group + ".") for n in new)
            if olds != news:
                if group not in said:
                    said.add(group)
                    out.append(
                        f"{group} {'run' if olds else 'absent'} (now {'run' if news else 'absent'})"
                    )
                continue
        out.append(f"{k} {old.get(k, 'unset')} (now {new.get(k, 'unset')})")
    return out


def recorded_number(x) -> float | None:
    """A number a ``results.json`` recorded: a finite int or float, else None (missing, null, NaN,
    infinite, a bool, a string of digits, an integer too large for a float); the index reads its
    tables with it too."""
    if not isinstance(x, int | float) or isinstance(x, bool):
        return None
    try:
        return float(x) if math.isfinite(x) else None
    except OverflowError:
        return None


#: Tables made before the beam search took the reference's tie order below depth 0 (``plan_ties``,
#: ``index``) planned with ties broken by the policy, a variant of ours (the outside review of
#: issue 55 found it): their planned rows are that variant, and their cells are not current.
PLAN_TIES_SINCE = "2026-12-06T11:02"  # commit 72c7fac
#: Tables made before the beam search drew depth-0 ties from the policy (``plan_order``,
#: ``sample``, the reference's) took them in the policy's argmax order, a variant of ours.
PLAN_ORDER_SINCE = "2026-12-01T19:55"  # commit 899a901


def made_before(summary: dict, since: str = PLAN_TIES_SINCE) -> bool:
    """Whether the table was made before ``since`` (a record without a date: no)."""
    created = summary.get("created")
    return isinstance(created, str) and created < since


def named(row: dict, summary: dict, env: str) -> dict:
    """``row`` with its backbone named as ``evaluation.compare`` names it now: a table whose spec
    gated every planned evaluation (``plan_gate``) recorded its planned rows as ``DICP + plan``,
    a variant that is not the reference planner, so it is read as ``DICP + plan, gated``; a table
    made before ``PLAN_TIES_SINCE`` planned with ties by policy (before ``PLAN_ORDER_SINCE`` also
    in argmax order at depth 0), which its rows on ``env`` then name where the planner is the beam
    search (discrete actions)."""
    backbone = row["backbone"]
    gate = (summary.get("experiment", {}).get("evaluate") or {}).get("plan_gate", "always")
    if gate != "always" and backbone.endswith(" + plan"):
        backbone += ", gated"
    beam = " + plan" in backbone and get_spec(env).is_discrete
    if beam and made_before(summary, PLAN_ORDER_SINCE) and "argmax order" not in backbone:
        backbone += ", argmax order"
    if beam and made_before(summary) and "ties by" not in backbone:
        backbone += ", ties by policy"
    return {**row, "backbone": backbone}


def cell_results(summary: dict, env: str, objective: str) -> list[dict]:
    """A table's rows of one env and backbone, each with its arm (one per sweep value);
    ``ValueError`` when the cells are malformed."""
    cells = summary.get("cells")
    if not isinstance(cells, list):
        raise UserError("cells is not a list")
    out = []
    for cell in cells:
        if not isinstance(cell, dict) or not isinstance(cell.get("rows"), list):
            raise UserError(f"a cell is malformed: {str(cell)[:60]}")
        if cell.get("env_id") != env:
            continue
        for row in cell["rows"]:
            if not isinstance(row, dict) or not isinstance(row.get("backbone"), str):
                raise UserError(f"a row is malformed: {str(row)[:60]}")
            if not isinstance(cell.get("arm"), str):
                raise UserError(f"a cell has no arm: {str(cell)[:60]}")
            if objective_of(row["backbone"]) == objective:
                row = named(row, summary, env)
                out.append({**row, "arm": cell["arm"], "E": recorded_number(row.get("E"))})
    return out


def _tables(root: Path) -> tuple[list[tuple[Path, dict]], list[str]]:
    """The tables under ``root`` and the names of those whose ``results.json`` cannot be read."""
    out, bad = [], []
    for path in sorted(root.glob("*/results.json")):
        try:
            summary = read_json(path)
            if not isinstance(summary["experiment"]["name"], str):
                raise TypeError
        except (OSError, ValueError, KeyError, TypeError):
            bad.append(path.parent.name)
            continue
        out.append((path.parent, summary))
    return out, bad


def exported_hashes(root: Path) -> tuple[dict[str, str], list[str]]:
    """``{stage hash: export folder name}`` of every evaluation in ``ROOT/stages/*/stages.json``
    (``lhf verify``/``--import-stages`` check them; here they are only read), and the exports
    whose index cannot be read, with the reason."""
    out, bad = {}, []
    folders = sorted(p for p in (root / "stages").glob("*") if p.is_dir())
    bad += [f"{p.name} (no stages.json)" for p in folders if not (p / "stages.json").is_file()]
    for index in sorted((root / "stages").glob("*/stages.json")):
        try:
            stages = read_json(index)["stages"]
            found = {s["hash"]: index.parent.name for s in stages if s["kind"] == "evaluate"}
            if not all(isinstance(h, str) for h in found):
                raise TypeError("a hash is not a string")
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            bad.append(f"{index.parent.name} ({type(exc).__name__}: {exc})")
            continue
        out.update(found)
    return out, bad


def reference_cpu() -> str:
    """The first shipped machine's CPU: its rates are the page's, whichever machine renders it."""
    return read_json(REFERENCE)["machines"][0]["cpu"]


def reference() -> dict:
    """``{key: rate}`` of the first shipped machine, others' for what it lacks."""
    return reference_rates(cpu=reference_cpu())


def _left(exp: Experiment, root: Path, exported: dict[str, str], reference: dict) -> dict:
    """What is left of ``exp``'s plan once the committed exports count as done: its estimated wall
    time at ``JOBS`` (of the measured stages only when ``missing`` names kinds never measured), the
    runs whose evaluations are all exported, and the exports that hold any."""
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


def coverage(
    root: str | Path,
    preset: str = "cpu",
    names: list[str] | None = None,
    unreadable: list[str] | tuple[str, ...] = (),
) -> dict:
    """Every shipped spec with ``preset`` (or ``names``): its cells (the preset's envs x
    backbones) with their status, and the envs of its grid the preset leaves out; and the tables
    and exports under ``root`` that could not be read (``ValueError`` for an unknown preset).
    ``unreadable``: tables the caller could not read (``index.py``), left out here too."""
    if preset not in PRESETS:
        raise UserError(f"unknown preset {preset!r}: one of {', '.join(PRESETS)}")
    root = Path(root)
    tables, malformed = _tables(root)
    malformed = {name: "unreadable" for name in malformed}
    for name in unreadable:
        malformed.setdefault(name, "unreadable in the index")
    tables = [(f, s) for f, s in tables if f.name not in malformed]
    exported, unread = exported_hashes(root)
    rates = reference()
    specs = []
    for name in names or experiment_names():
        try:
            exp = load_experiment(name, preset)
        except ValueError:
            continue  # a spec without this preset
        mine = []
        for folder, s in tables:
            if s["experiment"]["name"] != name or s["experiment"].get("preset") != preset:
                continue
            if s["experiment"].get("spec", name) != name:  # a custom yaml of a shipped spec's stem
                continue
            try:
                mine.append((folder, s, recorded_experiment(s, exp)))
            except ValueError as exc:
                malformed.setdefault(folder.name, str(exc))
        mine = [m for m in mine if m[0].name not in malformed]
        cells = []
        for env in exp.envs:
            for obj in exp.objectives:
                paper = recorded_number((exp.paper.get(env) or {}).get(obj))
                cell = {"env": env, "objective": obj, "paper": paper, "status": "not run"}
                found = []
                for folder, s, rec in mine:
                    try:
                        rows = cell_results(s, env, obj)
                    except ValueError as exc:
                        malformed.setdefault(folder.name, str(exc))
                        continue
                    if rows:
                        diff = differences(rec, exp, env, obj)
                        rank = (
                            not diff and rec.runs >= exp.runs,
                            not diff,
                            str(s.get("created") or ""),
                        )
                        found.append((rank, folder, s, rec, rows, diff))
                if found:
                    (current, same, _), folder, s, rec, rows, diff = max(found, key=lambda f: f[0])
                    stage_s = recorded_number(s.get("stage_s"))
                    cell.update(
                        status="done" if current else "fewer runs" if same else "other settings",
                        table=folder.name,
                        report=(folder / "report.md").is_file(),
                        stage_s=stage_s if stage_s and stage_s > 0 else None,
                        runs=rec.runs,
                        rows=rows,
                        differences=diff,
                    )
                if cell["status"] != "done":
                    one = dataclasses.replace(exp, envs=(env,), objectives=(obj,), narrowed=True)
                    cell["left"] = _left(one, root, exported, rates)
                cells.append(cell)
        outside = [
            {
                "env": env,
                "left": _left(dataclasses.replace(exp, envs=(env,)), root, exported, rates),
            }
            for env in _spec_envs(name)
            if env not in exp.envs
        ]
        specs.append({"experiment": exp, "cells": cells, "outside": outside})
    return {
        "preset": preset,
        "specs": specs,
        "malformed": [f"{name} ({why})" for name, why in sorted(malformed.items())],
        "malformed_names": sorted(malformed),
        "unread_exports": unread,
    }


def _estimate(left: dict) -> str:
    if left["missing"]:  # the key less its env (the row's): "evaluate dicp paper plan window"
        kinds = sorted(" ".join(k.split("|")[:1] + k.split("|")[2:]) for k in left["missing"])
        # a lower bound from the measured stages alone would mislead (a filter's seconds beside
        # a collection never timed): the cell's cost is unknown
        text = f"unknown: never measured ({', '.join(kinds)})"
    else:
        text = f"~{duration(left['wall_s'])}"
    if left["exported_runs"]:
        runs = ", ".join(map(str, left["exported_runs"]))
        text += f"; run {runs} exported in {', '.join(left['exports'])}"
    return text


def _ours(rows: list[dict]) -> str:
    parts = []
    for r in rows:
        arm = "" if r["arm"] == "lhf" else f" {r['arm']}"
        parts.append(f"{r['backbone']}{arm} {percent(r['E'])}")
    return ", ".join(parts).replace("|", "\\|")  # a pipe would end the table cell


def render_coverage(cov: dict) -> list[str]:
    """The coverage section of ``results/README.md`` (markdown lines)."""
    preset = cov["preset"]
    lines = [
        f"## Coverage at the {preset} preset",
        "",
        f"Every cell of every shipped spec at `--preset {preset}` (`scripts/results_coverage.py`). "
        "**done**: a table here holds it from the preset's runs, made with the settings its stages "
        "run with now (defaults included; a default changed inside the code is not seen); else the "
        "table closest to that: **fewer runs**, then **other settings** (named), the newest among "
        "equals; **not run**: no table here holds it. Left to run: the estimated wall time of the "
        "cell at `--jobs 2` (from scratch where it is not done, an older table's stages are not "
        "reused) from the reference rates "
        f"({reference_cpu()}; a rate it lacks from the other shipped machine, an AMD "
        "EPYC, which takes up to ~2x), less the evaluations committed under `stages/` "
        "(`--import-stages`); each cell alone, so a stage two cells share is counted in each; "
        "`unknown` where a kind of stage was never measured (named).",
        "",
        "| spec | env | backbone | paper E (%) | status | ours: E (%) | table (stage time) | left to run |",
        "|---|---|---|---|---|---|---|---|",
    ]
    done = total = unknown = 0
    left_s = 0.0
    for spec in cov["specs"]:
        exp = spec["experiment"]
        for c in spec["cells"]:
            total += 1
            paper = "-" if c["paper"] is None else f"{c['paper']:+.1f}"
            table = ours = "-"
            if "table" in c:
                table = (
                    f"[{c['table']}]({quote(c['table'])}/report.md)" if c["report"] else c["table"]
                )
                table += f" ({c['stage_s'] / 3600:.2f} h)" if c["stage_s"] else ""
                ours = _ours(c["rows"])
            status = c["status"]
            if status == "fewer runs":
                status += f" ({c['runs']} of {exp.runs})"
            elif status == "other settings":
                status += ": " + "; ".join(c["differences"])
            left = "-"
            if c["status"] == "done":
                done += 1
            else:
                left = _estimate(c["left"])
                if c["left"]["missing"]:
                    unknown += 1
                else:
                    left_s += c["left"]["wall_s"]
            lines.append(
                f"| {exp.name} | {c['env']} | {c['objective'].upper()} | {paper} | {status} "
                f"| {ours} | {table} | {left} |"
            )
    rest = total - done
    summary = f"{done} of {total} cells done at the {preset} preset's current settings"
    if rest > unknown:
        summary += (
            f"; the other {rest}" if not unknown else f"; {rest - unknown} of the other {rest}"
        )
        summary += f": ~{duration(left_s)} wall at `--jobs 2`, each cell alone"
    if unknown:
        summary += f"; {unknown} of unknown cost"
    lines += ["", summary + ".", ""]
    outside = [(s["experiment"], o) for s in cov["specs"] for o in s["outside"]]
    if outside:
        lines += [
            f"Envs of the specs' grids that the {preset} preset leaves out (its `budget` in the "
            "spec says why; the preset's backbones, from scratch, at `--jobs 2`; a spec of its own "
            "with `envs: [ENV]` gives the same from `lhf reproduce SPEC.yaml --estimate`):",
            "",
        ]
        lines += [f"- {exp.name}: {o['env']}, {_estimate(o['left'])}" for exp, o in outside]
        lines.append("")
    if cov["malformed"]:
        lines += [
            f"Tables left out (their `results.json` cannot be read, or its settings or cells not "
            f"rebuilt): {', '.join(cov['malformed'])}.",
            "",
        ]
    if cov["unread_exports"]:
        lines += [
            f"Exports not counted (their `stages.json` cannot be read): {', '.join(cov['unread_exports'])}.",
            "",
        ]
    return lines
