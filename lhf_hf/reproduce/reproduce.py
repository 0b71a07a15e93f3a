"""``reproduce(name, preset, ...)``: one paper experiment end to end (docs/reproduce.md,
``reproduce.py``), its stages cached under ``work`` by config hash; ``out`` gets only the report.
"""

from __future__ import annotations

import dataclasses
import hashlib
import shlex
import shutil
import time
from pathlib import Path

from lhf_hf import constants as C
from lhf_hf.collection import collect
from lhf_hf.collection.batched_collector import resolve_ppo_backend
from lhf_hf.configs import CollectConfig
from lhf_hf.envs import get_spec
from lhf_hf.errors import UserError, UserRuntimeError
from lhf_hf.evaluation import evaluate
from lhf_hf.evaluation.compare import compare, mean_curves
from lhf_hf.evaluation.evaluate import RESULTS_FILE as EVAL_RESULTS
from lhf_hf.evaluation.plots import plot_sweep
from lhf_hf.filtering.run import run_filter
from lhf_hf.filtering.select import CONFIG_FILE
from lhf_hf.histories.derive import derive_half
from lhf_hf.training import train
from lhf_hf.training.attention_backend import planned_attention_kernel
from lhf_hf.training.trainer import last_checkpoint
from lhf_hf.utils.io import read_json, write_bytes_atomic, write_json_atomic, write_text_atomic
from lhf_hf.utils.outputs import output_folder
from lhf_hf.utils.versions import library_versions

from .estimate import collect_cost, estimate, eval_cost, render, train_cost
from .experiment import Experiment, load_experiment, shadows_shipped, spec_path
from .parallel import check_jobs, run_stages, worker_command
from .portable import ExportError, check_export, export_stages, import_stages
from .report import SWEEP_FIGURE, command_line, default_out, render_report
from .stages import Cost, Stage, StageRunner, done_record, needed_stages, stage_wall

#: TrainConfig fields that say where the data, the model and the logs are, not what is trained: the
#: stage's hash covers its inputs' hashes instead.
TRAIN_PLACES = ("dataset", "selection", "out", "resume", "overwrite", "push_to_hub", "hub_private",
                "report_to")  # fmt: skip


def plan_stages(exp: Experiment, work: Path, progress: bool = True) -> tuple[list[Stage], dict]:
    """Every stage of ``exp`` in run order (their folders under ``work``), and
    ``evals[(env, arm or "baseline", objective)] -> [evaluate stage per run]``; also
    ``evals[("selection", env, arm)] -> [filter stage per run]`` (what each selection kept).
    A stage's hash covers its whole config, defaults included, and the hashes of the stages it
    reads; ``progress`` (the stages' bars) is in none."""
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
                collect(CollectConfig.from_dict(cfg.to_dict()), data, resume=data.exists(),
                        progress=progress)  # fmt: skip

            label = f"{tag}: {collect_cfg.histories} histories x {collect_cfg.steps}"
            col = Stage(
                "collect", label, collect_cfg.identity(), do_collect, cost=collect_cost(collect_cfg)
            )
            transitions = col.cost.units
            stages.append(col)
            data_stage = col
            if exp.half:

                def do_half(out: Path, src=col) -> None:
                    derive_half(
                        src.path(work) / "data", out / "data", overwrite=True, progress=progress
                    )

                data_stage = Stage("derive", f"{tag}: first half", {"src": col.hash}, do_half,
                                   (col,), Cost("derive", transitions))  # fmt: skip
                transitions /= 2
                stages.append(data_stage)
            arms = []
            for arm, filter_cfg in exp.filter_arms(run):

                def do_filter(out: Path, cfg=filter_cfg, src=data_stage) -> None:
                    run_filter(src.path(work) / "data", out / "selection", cfg, overwrite=True,
                               progress=progress)  # fmt: skip

                fc = {"src": data_stage.hash, **filter_cfg.to_dict()}
                sel = Stage("filter", f"{tag}: {arm}", fc, do_filter, (data_stage,),
                            Cost("filter", transitions))  # fmt: skip
                stages.append(sel)
                arms.append((arm, sel))
                evals.setdefault(("selection", env, arm), []).append(sel)
            for obj in exp.objectives:
                for arm, sel in [("baseline", None), *arms]:
                    train_cfg = exp.train_config(obj, run, dataset="", selection=None, out="")
                    # `auto` decided before the hash: the kernel and the torch path draw different
                    # dropout masks, so the attention code is part of what the stage's name says
                    attention = planned_attention_kernel(train_cfg)
                    tc = {k: v for k, v in train_cfg.to_dict().items() if k not in TRAIN_PLACES}
                    tc["attention_kernel"] = attention
                    # the hash of a stage from before a field: no Trainer arguments, the torch path
                    if not tc["training_args"]:
                        del tc["training_args"]
                    if attention == "torch":
                        del tc["attention_kernel"]
                    spec = get_spec(env)
                    if (
                        obj == "dicp" and tc["reward_weighting"] is None
                        and spec.is_discrete and spec.reward_values
                    ):  # fmt: skip
                        # unset meant 'actions' here (discrete actions, reward classes) before
                        # the default became the reference's 'data': the resolved value names
                        # the stage, so no old model passes for a new one
                        tc["reward_weighting"] = "data"
                    tc["src"] = data_stage.hash
                    if sel is not None:
                        tc["selection"] = sel.hash

                    def do_train(out: Path, obj=obj, run=run, src=data_stage, sel=sel,
                                 attention=attention) -> None:  # fmt: skip
                        model = out / "model"
                        resume = last_checkpoint(model) is not None
                        if model.is_dir() and not resume:
                            # nothing to resume: removed, not replaced by --overwrite, whose
                            # interrupted replace would put it back over the new checkpoints
                            shutil.rmtree(model)
                        selection = str(sel.path(work) / "selection") if sel else None
                        data = str(src.path(work) / "data")
                        cfg = exp.train_config(obj, run, dataset=data, selection=selection,
                                               out=str(model), resume=resume)  # fmt: skip
                        train(
                            dataclasses.replace(cfg, attention_kernel=attention), progress=progress
                        )

                    reads = (data_stage,) if sel is None else (data_stage, sel)
                    tr = Stage("train", f"{tag}: {obj.upper()} {arm}", tc, do_train, reads,
                               train_cost(env, train_cfg))  # fmt: skip
                    stages.append(tr)
                    for plan in exp.dicp_plan_modes() if obj == "dicp" else ("none",):
                        eval_cfg = exp.eval_config(run, model="", out="", plan=plan)
                        ec = {k: v for k, v in eval_cfg.to_dict().items() if k != "out"}
                        if ec["plan_reward_threshold"] is None:  # the hash from before the field
                            del ec["plan_reward_threshold"]
                        if not ec["plan"] or not spec.is_discrete:
                            del ec["plan_ties"]  # no beam search: the hash from before the field
                        ec["model"] = tr.hash

                        def do_eval(out: Path, run=run, plan=plan, tr=tr) -> None:
                            model = str(tr.path(work) / "model")
                            evaluate(
                                exp.eval_config(run, model=model, out=str(out / "eval"), plan=plan),
                                progress=progress,
                            )

                        what = f"{exp.column(obj, plan)} {arm}"
                        cost = eval_cost(env, obj, train_cfg, eval_cfg, run)
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
    progress: bool = True,
) -> Path:
    """Run experiment ``name`` at ``preset``; returns the path of ``report.md``.

    jobs: stages at once (``parallel.py``).  objectives: only these backbones (the report is named
    after them, a later full run reuses their stages).  import_from: exports (``portable.py``)
    copied into ``work`` first; what they hold is not run again.  progress: the stages' bars.
    """
    exp, work, stages, evals = _prepare(
        name, preset, runs, work, jobs, objectives, import_from, echo, progress
    )
    out = Path(report_out(exp, out))
    echo(f"[lhf reproduce] {_plan_line(exp, stages)}; work folder {work}, report in {out}")
    # the report is regenerated from the cache: an earlier one of ours is replaced (and put back
    # if this run fails); someone else's folder, or the cache itself, is refused
    with output_folder(out, "report", overwrite=True, inputs=[work], own_nested=["comparison"]):
        # the children plan from a copy: an edit of the spec meanwhile cannot reach them
        spec = snapshot_spec(name, preset, runs, exp, work, objectives) if jobs > 1 else None
        command = worker_command(spec, preset, exp.runs, work, progress) if spec else None
        return _run(exp, stages, evals, work, out, echo, jobs, command)


def _prepare(name, preset, runs, work, jobs, objectives, import_from, echo, progress=True):
    """The checked call's experiment, work folder and plan, the exports imported first."""
    check_jobs(jobs)
    if not str(work).strip():
        raise UserError("the work folder (--work) is empty: name the stage cache's folder")
    if Path(work).exists() and not Path(work).is_dir():
        raise UserError(f"--work {work}: a file, not a stage cache folder")
    exp = load_experiment(name, preset, runs, objectives)
    stages, evals = plan_stages(exp, Path(work), progress)
    for folder in import_from or ():  # every export checked before the first copy
        if problems := check_export(folder):
            raise ExportError(f"{problems[0]}: nothing was imported")
    for folder in import_from or ():
        _import(folder, Path(work), stages, echo, exp)
    return exp, Path(work), stages, evals


def _plan_line(exp: Experiment, stages: list[Stage]) -> str:
    return (
        f"{exp.spec or exp.name} ({exp.title}), preset {exp.preset}: {exp.runs} run(s) x "
        f"{len(exp.envs)} env(s) x {len(exp.objectives)} backbone(s), {len(stages)} stages"
    )


def report_out(exp: Experiment, out: str | Path | None = None) -> str | Path:
    """The report folder: ``out`` as given (not empty), else ``results/NAME-PRESET[-backbones]``,
    which a spec file named like a shipped spec has not (it would replace that table's report)."""
    if out is not None:
        if not str(out).strip():
            raise UserError("--out is empty: name the report's folder")
        return out
    default = default_out(exp.name, exp.preset, exp.objectives if exp.narrowed else None)
    if shadows_shipped(exp.name, exp.spec):
        raise UserError(
            f"{shlex.quote(exp.spec)} is named like the shipped spec {exp.name!r}, whose table's "
            f"folder is {default}: name this report's folder with --out"
        )
    return default


def snapshot_spec(name, preset, runs, exp: Experiment, work: Path, objectives=None) -> Path:
    """A copy of the spec under ``work/specs/<sha256>/`` (same file name), checked to load as the
    planned experiment; the children plan the whole spec and find their stage by its hash."""
    path = spec_path(name)
    text = path.read_bytes()
    copy = work / "specs" / hashlib.sha256(text).hexdigest()[:12] / path.name
    if not copy.exists():
        copy.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(text, copy)
    again = load_experiment(str(copy), preset, runs, objectives)
    if dataclasses.replace(again, spec=exp.spec) != exp:
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
    """``--estimate``: the plan's stages, which are cached, and the time of the rest
    (``estimate.py``), as text; runs nothing but the imports."""
    exp, work, stages, evals = _prepare(
        name, preset, runs, work, jobs, objectives, import_from, echo
    )
    needed = needed_stages(stages, work, _targets(evals))
    head = f"[lhf reproduce --estimate] {_plan_line(exp, stages)}"
    if left_out := len(stages) - len(needed):
        head += f" ({left_out} left out: what reads them is done)"
    try:
        head += f"; work folder {work}, report in {report_out(exp, out)}"
    except UserError as e:
        head += f"; work folder {work}; a run would be refused: {e}"
    return render(estimate(needed, work, jobs), head)


def export_experiment(name, dest, preset="quick", runs=None, work="runs/reproduce", objectives=None,
                      out=None) -> dict:  # fmt: skip
    """``--export-stages DEST``: this plan's finished evaluations to ``DEST`` (``portable.py``);
    returns the counts and ``command``, the call that imports them and finishes the table."""
    exp, work, stages, _ = _prepare(name, preset, runs, work, 1, objectives, None, None)
    about = {"experiment": exp.name, "preset": preset, "runs": exp.runs}
    about.update(objectives=list(exp.objectives), **_made())
    counts = export_stages(stages, work, dest, about)
    return {**counts, "command": import_command(exp, runs, dest, out)}


def import_command(exp: Experiment, runs: int | None, dest, out=None) -> str:
    """The shell-quoted call that imports ``dest`` and finishes the table (``--out FOLDER`` where
    the spec has no default report folder)."""
    if out is None and shadows_shipped(exp.name, exp.spec):
        out = "FOLDER"
    narrowed = exp.objectives if exp.narrowed else None
    line = command_line(exp.name, exp.preset, runs, narrowed, out, exp.spec)
    return f"{line} --import-stages {shlex.quote(str(dest))}"


def _made() -> dict:
    """When, and with which versions, a table or an export was made."""
    versions = library_versions(["transformers", "accelerate"])
    return {"versions": versions, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}


def _targets(evals: dict) -> list[Stage]:
    """The stages the report reads: every evaluation and every selection."""
    return [s for group in evals.values() for s in group]


def _import(folder, work: Path, plan: list[Stage], echo, exp: Experiment) -> None:
    n = import_stages(folder, work, plan)
    echo(
        f"[lhf reproduce] imported from {folder}: {n['imported']} evaluation(s), "
        f"{n['records']} record(s), {n['present']} already here; {n['evaluations_in_plan']} "
        f"of its {n['evaluations']} evaluation(s) are in this plan"
    )
    if n["evaluations"] and not n["evaluations_in_plan"]:
        a = n["about"]
        echo(
            f"[lhf reproduce] warning: none of {folder}'s evaluations is in this plan (it was "
            f"exported from {a.get('experiment')} --preset {a.get('preset')} --runs "
            f"{a.get('runs')}, this is {exp.name} --preset {exp.preset} --runs {exp.runs}; "
            "if they are the same: another code version, or a changed spec)"
        )


def _run(exp, stages, evals, work: Path, out: Path, echo, jobs: int, command) -> Path:
    t0 = time.perf_counter()
    todo = needed_stages(stages, work, _targets(evals))
    runner = StageRunner(work, total=len(todo), echo=echo)
    if len(todo) < len(stages):
        echo(f"[lhf reproduce] {len(stages) - len(todo)} stage(s) left out: not done, but what "
             "reads them is (imported evaluations)")  # fmt: skip
    run_stages(todo, runner, jobs, command)
    arms = [arm for arm, _ in exp.filter_arms(0)]

    def runs_of(env: str, arm: str) -> list[str]:  # every backbone's evaluations, run by run
        return [str(s.path(work) / "eval") for o in exp.objectives for s in evals[(env, arm, o)]]

    cells = []
    for env in exp.envs:
        for arm in arms:
            found = compare(
                runs_of(env, "baseline"), runs_of(env, arm), out=out / env / arm, overwrite=True
            )
            cells.append({"env_id": env, "arm": arm, **found})
    for env in exp.envs if len(arms) > 1 else ():  # a sweep: every value on one panel per backbone
        panels: dict[str, dict] = {}
        for arm in ["baseline", *arms]:
            for backbone, curves in mean_curves(runs_of(env, arm)).items():
                panels.setdefault(backbone, {})[arm] = curves  # (runs, episodes)
        title = f"{env}: baseline (dashed) vs LHF per {exp.filter['sweep']['key']} (solid)"
        plot_sweep(panels, out / env / SWEEP_FIGURE, title)
    selections = [
        {"env_id": env, "arm": arm, "run": run, **_selection_summary(stage.path(work))}
        for env in exp.envs
        for arm in arms
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
        # what the whole table cost, whichever call or machine ran each stage
        "stage_s": round(sum(stage_wall(s.path(work)) for s in stages), 1),
        "left_out": len(stages) - len(todo),
        "imported": [
            {"stage": s.label, **origin}
            for s in stages
            if (origin := (done_record(s.path(work)) or {}).get("imported"))
        ],
        "jobs": jobs,
        **_made(),
    }
    write_json_atomic(summary, out / "results.json")
    report = out / "report.md"
    write_text_atomic(render_report(exp, cells, summary, out), report)
    echo(f"[lhf reproduce] report: {report}  ({wall} s)")
    return report


def _selection_summary(folder: Path) -> dict:
    """What a selection kept: histories kept and rejected, and each group's mean return."""
    found = read_json(folder / "selection" / CONFIG_FILE)["summary"]
    fields = ("histories", "selected_unique", "rejected", "mean_return_source",
              "mean_return_selected_unique", "mean_return_rejected", "mean_return_selection",
              "within_task")  # fmt: skip
    return {k: found.get(k) for k in fields}


def _other_data(evals: dict, work: Path) -> list[dict]:
    """The evaluations whose model trained on another draw of the collection than the one here
    (imported from a machine of another instruction set, docs/histories.md): the selection summary
    then describes this machine's data, not theirs."""
    found = []
    for ev in (s for key, group in evals.items() if key[0] != "selection" for s in group):
        data = next(s for s in ev.inputs[0].inputs if s.kind in ("collect", "derive"))
        try:
            model = read_json(ev.path(work) / "eval" / EVAL_RESULTS)["model"]
            used = model["dataset"]["fingerprint"]
            here = read_json(data.path(work) / "data" / C.LHF_INFO_PATH)
        except (OSError, ValueError, KeyError, TypeError):
            continue  # nothing recorded to compare
        mine = here.get("fingerprint")
        if isinstance(used, str) and isinstance(mine, str) and used != mine:
            machine = here.get("machine") or {}
            found.append({"stage": ev.label, "trained_on": used, "here": mine,
                          "here_machine": {k: machine.get(k) for k in ("cpu", "isa", "threads")}})  # fmt: skip
    return found
