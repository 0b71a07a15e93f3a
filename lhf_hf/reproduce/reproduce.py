"""``reproduce(name, preset, runs, out, work)``: one paper experiment end to end.

Per run r (seed r, train/test split r) and env: collect the train tasks' histories (optionally keep
the first half of each), filter them with LHF (one selection per filter arm: the experiment's filter,
or each value of its sweep), then per backbone train a baseline and an LHF model and evaluate both on
the run's unseen tasks.  Then per env and arm: ``compare`` over the runs (E with its std over paired
runs), and ``report.md`` beside the paper's numbers.  Every stage is cached by its config hash under
``work`` (datasets and checkpoints: git-ignored); ``out`` gets only reports, JSON and PNGs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shlex
import shutil
import time
from pathlib import Path

from lhf_hf.collection import collect
from lhf_hf.collection.batched_collector import resolve_ppo_backend
from lhf_hf.configs import CollectConfig
from lhf_hf.errors import UserError, UserRuntimeError
from lhf_hf.evaluation import evaluate
from lhf_hf.evaluation.compare import compare, mean_curves
from lhf_hf.evaluation.evaluate import RESULTS_FILE as EVAL_RESULTS
from lhf_hf.evaluation.plots import plot_sweep
from lhf_hf.filtering.run import run_filter
from lhf_hf.filtering.select import CONFIG_FILE
from lhf_hf.histories.derive import derive_half
from lhf_hf.training import train
from lhf_hf.training.trainer import last_checkpoint
from lhf_hf.utils.io import read_json, write_bytes_atomic, write_json_atomic, write_text_atomic
from lhf_hf.utils.outputs import output_folder
from lhf_hf.utils.versions import library_versions

from .estimate import collect_cost, data_cost, estimate, eval_cost, render, train_cost
from .experiment import Experiment, load_experiment, shadows_shipped, spec_path
from .parallel import check_jobs, run_stages, worker_command
from .portable import export_stages, import_stages
from .report import SWEEP_FIGURE, render_report
from .report import default_out as report_folder
from .stages import Stage, StageRunner, done_record, needed_stages, stage_wall


def _arms(exp: Experiment) -> list[str]:
    return [arm for arm, _ in exp.filter_arms(0)]


#: TrainConfig fields that say where the data and the model are, not what is trained: the stage's
#: hash covers its inputs' hashes instead.
_TRAIN_PLACES = ("dataset", "selection", "out", "resume", "overwrite", "push_to_hub", "hub_private")


def plan_stages(exp: Experiment, work: Path) -> tuple[list[Stage], dict]:
    """Every stage of ``exp`` in run order (their folders under ``work``), and
    ``evals[(env, arm or "baseline", objective)] -> [evaluate stage per run]``; also
    ``evals[("selection", env, arm)] -> [filter stage per run]`` (what each selection kept).

    A stage's hash covers its whole config (every field, defaults included: a changed default
    re-runs what it changes) and the hashes of the stages it reads.
    """
    stages: list[Stage] = []
    evals: dict[tuple[str, str, str], list[Stage]] = {}
    for run in range(exp.runs):
        for env in exp.envs:
            tag = f"{env} run {run}"
            collect_cfg = exp.collect_config(env, run)
            if collect_cfg.collector == "batched":
                # `auto` decided before the hash: the kernel and torch ops draw their random
                # numbers differently, so the backend is part of what the stage's name says
                collect_cfg.ppo_backend = resolve_ppo_backend(collect_cfg)

            def do_collect(out: Path, cfg=collect_cfg) -> None:
                data = out / "data"
                collect(CollectConfig.from_dict(cfg.to_dict()), data, resume=data.exists())

            label = f"{tag}: {collect_cfg.histories} histories x {collect_cfg.steps}"
            col = Stage(
                "collect", label, collect_cfg.identity(), do_collect, cost=collect_cost(collect_cfg)
            )
            transitions = col.cost.units
            stages.append(col)
            data_stage = col
            if exp.half:

                def do_half(out: Path, src=col) -> None:
                    derive_half(src.path(work) / "data", out / "data", overwrite=True)

                data_stage = Stage(
                    "derive",
                    f"{tag}: first half",
                    {"src": col.hash},
                    do_half,
                    inputs=(col,),
                    cost=data_cost("derive", transitions),
                )
                transitions /= 2
                stages.append(data_stage)
            arms = []
            for arm, filter_cfg in exp.filter_arms(run):

                def do_filter(out: Path, cfg=filter_cfg, src=data_stage) -> None:
                    run_filter(src.path(work) / "data", out / "selection", cfg, overwrite=True)

                fc = {"src": data_stage.hash, **filter_cfg.to_dict()}
                sel = Stage(
                    "filter",
                    f"{tag}: {arm}",
                    fc,
                    do_filter,
                    (data_stage,),
                    data_cost("filter", transitions),
                )
                stages.append(sel)
                arms.append((arm, sel))
                evals.setdefault(("selection", env, arm), []).append(sel)
            for obj in exp.objectives:
                for arm, sel in [("baseline", None), *arms]:
                    train_cfg = exp.train_config(obj, run, dataset="", selection=None, out="")
                    tc = {k: v for k, v in train_cfg.to_dict().items() if k not in _TRAIN_PLACES}
                    tc["src"] = data_stage.hash
                    if sel is not None:
                        tc["selection"] = sel.hash

                    def do_train(out: Path, obj=obj, run=run, src=data_stage, sel=sel) -> None:
                        model = out / "model"
                        resume = last_checkpoint(model) is not None
                        if model.is_dir() and not resume:
                            # the stage's own folder, with nothing to resume (killed before its
                            # first checkpoint): removed, not replaced by --overwrite, which
                            # sets it aside and, interrupted, puts it back over the new
                            # checkpoints
                            shutil.rmtree(model)
                        cfg = exp.train_config(
                            obj,
                            run,
                            dataset=str(src.path(work) / "data"),
                            selection=str(sel.path(work) / "selection") if sel else None,
                            out=str(model),
                            resume=resume,
                        )
                        train(cfg)

                    tr = Stage(
                        "train",
                        f"{tag}: {obj.upper()} {arm}",
                        tc,
                        do_train,
                        (data_stage,) if sel is None else (data_stage, sel),
                        train_cost(env, train_cfg),
                    )
                    stages.append(tr)
                    for plan in exp.dicp_plan_modes() if obj == "dicp" else (False,):
                        eval_cfg = exp.eval_config(run, model="", out="", plan=plan)
                        ec = {k: v for k, v in eval_cfg.to_dict().items() if k != "out"}
                        ec["model"] = tr.hash

                        def do_eval(out: Path, run=run, plan=plan, tr=tr) -> None:
                            model = str(tr.path(work) / "model")
                            evaluate(
                                exp.eval_config(run, model=model, out=str(out / "eval"), plan=plan)
                            )

                        what = f"{obj.upper()}{' + plan' if plan else ''} {arm}"
                        cost = eval_cost(env, obj, train_cfg, eval_cfg, split_seed=run)
                        ev = Stage("evaluate", f"{tag}: {what}", ec, do_eval, (tr,), cost)
                        stages.append(ev)
                        evals.setdefault((env, arm, obj), []).append(ev)
    return stages, evals


def reproduce(
    name: str,
    preset: str = "quick",
    runs: int | None = None,
    out: str | Path | None = None,
    work: str | Path = "runs/reproduce",
    echo=print,
    jobs: int = 1,
    objectives: list[str] | None = None,
    import_from: list[str | Path] | None = None,
) -> Path:
    """Run experiment ``name`` at ``preset``; returns the path of ``report.md``.

    jobs: stages run at once; above 1 each runs in its own process with one thread
        (``parallel.py``; 1.3x on 2 cores for trainings).
    objectives: only these of the spec's backbones (None: all); the report is then named after
        them (``results/NAME-PRESET-dicp``) and a later full run reuses their stages.
    import_from: folders of finished stages exported elsewhere (``export_experiment``), copied
        into ``work`` first; what they hold is not run again (``portable.py``).
    """
    check_jobs(jobs)
    work = check_work(work)
    exp = load_experiment(name, preset, runs, objectives)
    out = Path(report_out(exp, out))
    stages, evals = plan_stages(exp, work)
    _import(import_from, work, stages, echo, exp)
    echo(
        f"[lhf reproduce] {exp.spec or exp.name} ({exp.title}), preset {preset}: {exp.runs} run(s) x "
        f"{len(exp.envs)} env(s) x {len(exp.objectives)} backbone(s), {len(stages)} stages; "
        f"work folder {work}, report in {out}"
    )
    # The report folder is regenerated from the stage cache: an earlier report of ours is replaced
    # (and put back if this run fails); someone else's folder, or the cache itself, is refused.
    if jobs > (os.cpu_count() or 1):
        echo(
            f"[lhf reproduce] warning: --jobs {jobs} on {os.cpu_count()} cores: the stages will "
            "share cores (one thread each), which is slower than --jobs equal to the cores"
        )
    with output_folder(
        out, "report", overwrite=True, inputs=[work], legacy=REPORT_FILES, own_nested=["comparison"]
    ):
        command = None
        if (
            jobs > 1
        ):  # the children plan from a copy: an edit of the spec meanwhile cannot reach them
            command = worker_command(
                snapshot_spec(name, preset, runs, exp, work, objectives), preset, exp.runs, work
            )
        return _run(exp, stages, evals, work, out, echo, jobs, command)


def report_out(exp: Experiment, out: str | Path | None) -> str | Path:
    """The report folder: ``out`` as given, else ``default_out``; an empty one is refused (it
    would be the current folder)."""
    if out is None:
        return default_out(exp)
    if not str(out).strip():
        raise UserError("--out is empty: name the report's folder")
    return out


def default_out(exp: Experiment) -> str:
    """``results/NAME-PRESET``, with the backbones appended when the grid is narrowed.  A spec
    file outside the package named like a shipped spec (``mine/darkroom-main.yaml``) has none:
    its default would be the shipped table's folder, whose report it would replace."""
    out = report_folder(exp.name, exp.preset, exp.objectives if exp.narrowed else None)
    if shadows_shipped(exp.name, exp.spec):
        raise UserError(
            f"{shlex.quote(exp.spec)} is named like the shipped spec {exp.name!r}, whose table's "
            f"folder is {out}: name this report's folder with --out"
        )
    return out


def snapshot_spec(
    name: str,
    preset: str,
    runs: int | None,
    exp: Experiment,
    work: Path,
    objectives: list[str] | None = None,
) -> Path:
    """A copy of the spec file under ``work/specs/<hash>/`` (same file name, so the same
    experiment name), checked to load as the experiment this call planned.  The children plan the
    whole spec and run their stage by its hash, which a narrowed plan shares with the full one."""
    path = spec_path(name)
    text = path.read_bytes()
    copy = work / "specs" / hashlib.sha256(text).hexdigest()[:12] / path.name
    if not copy.exists():
        copy.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(text, copy)
    # the copy is named by its path (``spec``), the planned experiment by what the user gave
    if (
        dataclasses.replace(load_experiment(str(copy), preset, runs, objectives), spec=exp.spec)
        != exp
    ):
        raise UserRuntimeError(
            f"the spec {name!r} changed while this run was starting: run it again"
        )
    return copy


def estimate_experiment(
    name: str,
    preset: str = "quick",
    runs: int | None = None,
    work: str | Path = "runs/reproduce",
    jobs: int = 1,
    objectives: list[str] | None = None,
    import_from: list[str | Path] | None = None,
    echo=print,
    out: str | Path | None = None,
) -> str:
    """``lhf reproduce ... --estimate``: the stages, which are cached, and the time the rest takes
    on this machine (``estimate.py``), as text; runs nothing (``import_from`` is imported first,
    as by ``reproduce``, so the estimate covers what is left).  Names the report folder the run
    would write (``out``, else the default), or why a run would be refused one."""
    check_jobs(jobs)
    work = check_work(work)
    exp = load_experiment(name, preset, runs, objectives)
    stages, evals = plan_stages(exp, work)
    _import(import_from, work, stages, echo, exp)
    needed = needed_stages(stages, work, _targets(evals))
    est = estimate(needed, work, jobs)
    left_out = len(stages) - len(needed)
    head = (
        f"[lhf reproduce --estimate] {exp.spec or exp.name}, preset {preset}: {exp.runs} run(s) x "
        f"{len(exp.envs)} env(s) x {len(exp.objectives)} backbone(s), {len(stages)} stages"
        + (f" ({left_out} left out: what reads them is done)" if left_out else "")
        + f"; work folder {work}"
    )
    try:
        head += f", report in {report_out(exp, out)}"
    except ValueError as e:
        head += f"; a run would be refused: {e}"
    return render(est, head)


def export_experiment(
    name: str,
    dest: str | Path,
    preset: str = "quick",
    runs: int | None = None,
    work: str | Path = "runs/reproduce",
    objectives: list[str] | None = None,
    out: str | Path | None = None,
) -> dict:
    """``lhf reproduce ... --export-stages DEST``: copy this plan's finished evaluations (and the
    records of its other finished stages) from ``work`` to ``DEST``, to commit or carry to another
    machine and import there (``portable.py``); runs nothing.  Returns the counts and
    ``command``, the call that imports them and finishes the table elsewhere (with ``out``, the
    report folder, when given; a placeholder ``FOLDER`` where the spec has no default one)."""
    work = check_work(work)
    exp = load_experiment(name, preset, runs, objectives)
    stages, _ = plan_stages(exp, work)
    about = {
        "experiment": exp.name,
        "preset": preset,
        "runs": exp.runs,
        "objectives": list(exp.objectives),
        "versions": library_versions(["transformers", "accelerate"]),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    counts = export_stages(stages, work, dest, about)
    return {**counts, "command": import_command(exp, runs, dest, out)}


def import_command(
    exp: Experiment, runs: int | None, dest: str | Path, out: str | Path | None = None
) -> str:
    """The call that imports an export (``dest``) and finishes the table elsewhere, shell-quoted:
    the spec as it was named, its preset, ``runs`` as given, the narrowed objectives, ``out``
    when given (a placeholder ``FOLDER`` where the spec has no default report folder)."""
    parts = ["lhf reproduce", shlex.quote(exp.spec or exp.name), "--preset", exp.preset]
    parts += [] if runs is None else ["--runs", str(runs)]
    parts += ["--objectives", *exp.objectives] if exp.narrowed else []
    if out is not None:
        parts += ["--out", shlex.quote(str(out))]
    elif shadows_shipped(exp.name, exp.spec):
        parts += ["--out", "FOLDER"]  # no default: the shipped table's folder is not its own
    return " ".join([*parts, "--import-stages", shlex.quote(str(dest))])


def check_work(work: str | Path) -> Path:
    """The stage cache's folder: refused when empty (``--work ''`` would be the current folder) or
    when it is a file (a mistyped path would otherwise be estimated as an empty cache)."""
    if not str(work).strip():
        raise UserError("the work folder (--work) is empty: name the stage cache's folder")
    path = Path(work)
    if path.exists() and not path.is_dir():
        raise UserError(f"--work {work}: a file, not a stage cache folder")
    return path


def _targets(evals: dict) -> list[Stage]:
    """The stages the report reads: every evaluation and every selection."""
    return [s for group in evals.values() for s in group]


def _import(folders, work: Path, plan: list[Stage], echo, exp: Experiment) -> None:
    for folder in folders or ():  # every folder checked before the first copy
        import_stages(folder, work, plan, dry=True)
    for folder in folders or ():
        n = import_stages(folder, work, plan)
        echo(
            f"[lhf reproduce] imported from {folder}: {n['imported']} evaluation(s), "
            f"{n['records']} record(s), {n['present']} already here; {n['evaluations_in_plan']} "
            f"of its {n['evaluations']} evaluation(s) are in this plan"
        )
        if n["evaluations"] and not n["evaluations_in_plan"]:
            about = n["about"]
            theirs = (about.get("experiment"), about.get("preset"), about.get("runs"))
            ours = (exp.name, exp.preset, exp.runs)
            why = (
                f"it was exported from {theirs[0]} --preset {theirs[1]} --runs {theirs[2]}, "
                f"this is {ours[0]} --preset {ours[1]} --runs {ours[2]}"
                if theirs != ours
                else "same experiment, preset and runs: another code version, or a changed spec?"
            )
            echo(f"[lhf reproduce] warning: none of {folder}'s evaluations is in this plan ({why})")


#: Files of a report folder written before output markers existed (``utils.outputs``).
REPORT_FILES = ("results.json", "report.md")


def _run(
    exp: Experiment,
    stages: list[Stage],
    evals: dict,
    work: Path,
    out: Path,
    echo,
    jobs: int,
    command,
) -> Path:
    t0 = time.perf_counter()
    todo = needed_stages(stages, work, _targets(evals))
    runner = StageRunner(work, total=len(todo), echo=echo)
    if len(todo) < len(stages):
        echo(
            f"[lhf reproduce] {len(stages) - len(todo)} stage(s) left out: not done, but what "
            "reads them is (imported evaluations, or a stage whose mark is no record while all "
            "after it are finished)"
        )
    run_stages(todo, runner, jobs, command)
    cells = []
    for env in exp.envs:
        for arm in _arms(exp):
            base = [
                str(s.path(work) / "eval")
                for o in exp.objectives
                for s in evals[(env, "baseline", o)]
            ]
            filt = [
                str(s.path(work) / "eval") for o in exp.objectives for s in evals[(env, arm, o)]
            ]
            res = compare(base, filt, out=out / env / arm, overwrite=True)
            cells.append({"env_id": env, "arm": arm, **res})
        if len(_arms(exp)) > 1:  # a sweep: every value on one panel per backbone, as the paper
            _plot_sweep(exp, env, evals, work, out / env / SWEEP_FIGURE)
    selections = [
        {"env_id": env, "arm": arm, "run": run, **_selection_summary(stage.path(work))}
        for env in exp.envs
        for arm in _arms(exp)
        for run, stage in enumerate(evals[("selection", env, arm)])
    ]
    wall = round(time.perf_counter() - t0, 1)
    summary = {
        "experiment": exp.to_dict(),
        "cells": cells,
        "selections": selections,
        "other_data": _other_data(evals, work),
        "stages": runner.log,
        "wall_s": wall,
        # what the whole table cost, whichever call ran each stage (a cached stage's own record)
        "stage_s": round(sum(stage_wall(s.path(work)) for s in stages), 1),
        "left_out": len(stages) - len(todo),  # not needed: what reads them is done (imported)
        # evaluations made on another machine (``--import-stages``): where from, which versions
        "imported": [
            {"stage": s.label, **origin} for s in stages if (origin := _imported(s.path(work)))
        ],
        "jobs": jobs,
        "versions": library_versions(["transformers", "accelerate"]),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    write_json_atomic(summary, out / "results.json")
    report = out / "report.md"
    write_text_atomic(render_report(exp, cells, summary, out), report)
    echo(f"[lhf reproduce] report: {report}  ({wall} s)")
    return report


def _plot_sweep(exp: Experiment, env: str, evals: dict, work: Path, path: Path) -> None:
    """One panel per backbone: the baseline and every swept value's LHF curves (fig_sensitivity)."""
    panels: dict[str, dict] = {}
    for arm in ["baseline", *_arms(exp)]:
        paths = [str(s.path(work) / "eval") for o in exp.objectives for s in evals[(env, arm, o)]]
        for backbone, runs in mean_curves(paths).items():
            panels.setdefault(backbone, {})[arm] = runs  # (runs, episodes)
    sweep = exp.filter["sweep"]["key"]
    plot_sweep(panels, path, f"{env}: baseline (dashed) vs LHF per {sweep} (solid)")


#: What the report says of each selection (``Selection.summary``): histories kept and rejected and
#: the mean return of each group, per history over its episodes.
SELECTION_FIELDS = (
    "histories",
    "selected_unique",
    "rejected",
    "mean_return_source",
    "mean_return_selected_unique",
    "mean_return_rejected",
    "mean_return_selection",
)


def _selection_summary(folder: Path) -> dict:
    """A finished filter stage's selection summary (the fields above; absent ones are None)."""
    found = read_json(folder / "selection" / CONFIG_FILE).get("summary") or {}
    return {k: found.get(k) for k in SELECTION_FIELDS}


def _other_data(evals: dict, work: Path) -> list[dict]:
    """The evaluations whose model trained on another collection than the one under ``work``
    that its stage reads: the same config, made again on a machine of another instruction set (a
    dataset is the same at any thread count, not across instruction sets; docs/histories.md).
    That happens when evaluations are imported (``--import-stages``) and the collection is
    re-made here for the report: its selection summary then describes this machine's draw, not
    the data the compared models trained on.  Each: the stage, both fingerprints, the machine."""
    found = []
    for key, stages in evals.items():
        if key[0] == "selection":
            continue
        for ev in stages:
            (tr,) = ev.inputs
            data = next(s for s in tr.inputs if s.kind in ("collect", "derive"))
            try:
                model = json.loads((ev.path(work) / "eval" / EVAL_RESULTS).read_text())["model"]
                used = model["dataset"]["fingerprint"]
                info = json.loads((data.path(work) / "data" / "meta" / "info.json").read_text())
                here = info["lhf"]["fingerprint"]
            except (OSError, ValueError, KeyError, TypeError):
                continue  # an older evaluation or dataset without the record: nothing to compare
            if not (isinstance(used, str) and isinstance(here, str)):
                continue  # no fingerprint recorded (null, edited): nothing to compare
            if used != here:
                machine = info["lhf"].get("machine")
                machine = machine if isinstance(machine, dict) else {}
                found.append(
                    {
                        "stage": ev.label,
                        "trained_on": used,
                        "here": here,
                        "here_machine": {k: machine.get(k) for k in ("cpu", "isa", "threads")},
                    }
                )
    return found


def _imported(folder: Path) -> dict | None:
    """Where a finished stage's output was imported from (None: made here)."""
    return (done_record(folder) or {}).get("imported")


def load_summary(out: str | Path) -> dict:
    return json.loads((Path(out) / "results.json").read_text())
