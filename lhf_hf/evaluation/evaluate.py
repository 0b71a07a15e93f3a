"""``evaluate(cfg)``: roll a checkpoint out in context on unseen tasks; results, curve, model card."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from transformers import AutoConfig

from lhf_hf.configs.evaluate import EvalConfig
from lhf_hf.envs import SPLIT_PARTS, get_spec, split_part
from lhf_hf.errors import UserError
from lhf_hf.modeling import load_model
from lhf_hf.training.card import MODEL_EVALS_FILE, evaluation_problems, write_model_card
from lhf_hf.training.model_config import check_model_env
from lhf_hf.training.trainer import TRAIN_CONFIG_FILE
from lhf_hf.utils.hub import is_hub_snapshot, resolve, source_of
from lhf_hf.utils.io import read_json, write_json_atomic
from lhf_hf.utils.outputs import changed_since_written, file_lock, output_folder
from lhf_hf.utils.versions import library_versions

from .plots import plot_eval_curve
from .rollout import rollout
from .seen import check_unseen, seen_label
from .task_batch import make_task_batch

RESULTS_FILE = "eval_results.json"
CURVE_FILE = "eval_curve.png"


def resolve_tasks(spec_env: str, tasks: str, split_seed: int) -> list[int]:
    """``test`` | ``train`` | ``validation`` | ``fit`` (parts of split ``split_seed``) or task
    indices ``"0,3,7"`` -> task indices."""
    if tasks in SPLIT_PARTS:
        return split_part(spec_env, tasks, split_seed)
    return [int(t) for t in tasks.split(",")]


def curve_summary(returns: np.ndarray) -> dict:
    """returns: (tasks, episodes) -> mean curve over tasks and its whole-curve / end values."""
    curve = returns.mean(0)
    tail = max(1, len(curve) // 10)
    return {
        "mean_curve": curve.tolist(),
        "mean_return": float(curve.mean()),
        "final_return": float(curve[-tail:].mean()),  # the last 10% of the episodes
        "first_return": float(curve[0]),
    }


def plan_label(cfg: EvalConfig) -> str:
    """' + planning' and how it deviates from the reference's defaults ('' without planning)."""
    if not cfg.plan:
        return ""
    how = [
        *(["gated on a seen reward"] if cfg.plan_gate != "always" else []),
        *(["true dynamics"] if cfg.plan_dynamics != "model" else []),
        *(["argmax order"] if cfg.plan_order != "sample" else []),
        *(["ties by policy"] if cfg.plan_ties != "index" else []),
        *([f"rewards at p >= {cfg.plan_reward_threshold:g}"] if cfg.plan_reward_threshold else []),
    ]
    return " + planning" + (f" ({', '.join(how)})" if how else "")


def evaluate(cfg: EvalConfig, progress: bool = True) -> dict:
    """Run ``cfg``; write ``eval_results.json`` and ``eval_curve.png`` to ``cfg.out``; add the result
    to the checkpoint's card.  Returns the results dict."""
    done: list = []  # (results, model folder), once the rollouts are written

    def enter_card() -> None:
        # within the folder's switch: the card lists an evaluation exactly when it is complete
        results, model_dir = done[0]
        if not is_hub_snapshot(model_dir):  # never write into the Hub cache; push the card
            _add_to_model_card(model_dir, results)

    with output_folder(
        cfg.out,
        "evaluation",
        overwrite=cfg.overwrite,
        inputs=[cfg.model],
        legacy=[RESULTS_FILE],
        on_switch=enter_card,
    ):
        done.append(_evaluate_into(cfg, progress))
    return done[0][0]


def _evaluate_into(cfg: EvalConfig, progress: bool) -> tuple[dict, Path]:
    model_dir = resolve(cfg.model, "model", "model checkpoint")
    changed = changed_since_written(
        model_dir, ["config.json", "model.safetensors", TRAIN_CONFIG_FILE]
    )
    if changed:  # its record of the training tasks (config.json) decides what is unseen
        raise UserError(
            f"{cfg.model}: {', '.join(changed)} changed since `lhf train` wrote it (its manifest "
            "says otherwise): not evaluated; `lhf verify` shows what changed"
        )
    evals_path = model_dir / MODEL_EVALS_FILE
    if evals_path.is_file() and not is_hub_snapshot(model_dir):  # before the rollouts, not after
        for problem in evaluation_problems(read_json(evals_path)):
            raise UserError(f"{evals_path} {problem}: the file is damaged (not evaluated)")
    model = load_model(str(model_dir))
    mc = model.config
    env_id = cfg.env_id or mc.env_id
    if env_id is None:
        raise UserError(f"{cfg.model} does not name its env: pass --env")
    spec = get_spec(env_id)
    check_model_env(mc, spec)
    if mc.env_id and env_id != mc.env_id:
        raise UserError(f"the model was trained on {mc.env_id!r}, not on {env_id!r}")
    if cfg.plan and mc.objective != "dicp":
        raise UserError(
            f"--plan needs a model with dynamics heads (objective dicp); {cfg.model} is {mc.objective!r}"
        )
    train_cfg_path = model_dir / TRAIN_CONFIG_FILE
    train_cfg = read_json(train_cfg_path) if train_cfg_path.exists() else None
    recorded = ((train_cfg or {}).get("dataset") or {}).get("tasks")
    if recorded is not None and mc.train_tasks is not None and sorted(recorded) != mc.train_tasks:
        # two records of one training disagree: one was edited (a folder without a manifest)
        raise UserError(
            f"{cfg.model}: config.json's train_tasks ({len(mc.train_tasks)} tasks) disagree with "
            f"{TRAIN_CONFIG_FILE}'s dataset tasks ({len(recorded)}): one was edited; not evaluated"
        )
    split_seed = cfg.split_seed
    if split_seed is None:  # the model's own split (its config: checkpoint-N folders have it too)
        split_seed = mc.split_seed if mc.split_seed is not None else 0
    tasks = resolve_tasks(env_id, cfg.tasks, split_seed)
    seen = check_unseen(spec, mc, tasks, split_seed, cfg.allow_seen, cfg.model)
    # rollout-major copies: row r * len(tasks) + i of the batch is task tasks[i], rollout r
    batch = make_task_batch(env_id, tasks * cfg.rollouts, split_seed, cfg.seed)
    res = rollout(
        model,
        batch,
        cfg.episodes,
        seed=cfg.seed,
        plan=cfg.plan,
        context=cfg.context,
        progress=progress,
        plan_dynamics=cfg.plan_dynamics,
        plan_order=cfg.plan_order,
        plan_ties=cfg.plan_ties,
        plan_gate=cfg.plan_gate,
        plan_reward_threshold=cfg.plan_reward_threshold,
    )
    out = Path(cfg.out)
    results = {
        "config": cfg.to_dict(),
        "env_id": env_id,
        "split_seed": split_seed,
        "tasks": tasks,
        # the evaluated tasks the model trained on ([] = all unseen; None = not recorded)
        "seen_tasks": seen,
        "task_label": seen_label(seen, len(tasks), cfg.tasks),
        "objective": mc.objective,
        "model": {
            "path": source_of(cfg.model, model_dir),
            "objective": mc.objective,
            "selection": (train_cfg or {}).get("selection"),
            "dataset": (train_cfg or {}).get("dataset"),
            "train": (train_cfg or {}).get("train"),
        },
        "rollouts": cfg.rollouts,
        # (rollouts * tasks, episodes), rollout-major: row r * len(tasks) + i is tasks[i], rollout r
        "returns": res.returns.tolist(),
        "success": None if res.success is None else res.success.astype(int).tolist(),
        **curve_summary(res.returns),
        # each rollout's whole-curve mean over the tasks: the spread a single rollout would show
        "rollout_mean_returns": res.returns.reshape(cfg.rollouts, len(tasks), -1)
        .mean((1, 2))
        .tolist(),
        "success_rate": None if res.success is None else float(res.success.mean()),
        "wall_s": round(res.wall_s, 3),
        "env_steps": res.env_steps,
        "env_steps_per_s": round(res.env_steps / res.wall_s, 1),
        "planned_steps": res.planned_steps,
        "planned_actions": res.planned_actions,
        "engine": res.engine,
        "plan_engine": res.plan_engine,
        "context": res.context,
        "versions": library_versions(["transformers"]),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    write_json_atomic(results, out / RESULTS_FILE)
    optimal = spec.optimal_returns()[tasks].mean() if spec.optimal_returns is not None else None
    plot_eval_curve(
        {f"{mc.objective.upper()}{plan_label(cfg)}": res.returns},
        out / CURVE_FILE,
        title=_curve_title(env_id, len(tasks), cfg.tasks, results["task_label"]),
        optimal=optimal,
    )
    return results, model_dir


def _curve_title(env_id: str, num_tasks: int, tasks: str, label: str) -> str:
    """``darkroom: 8 test tasks, unseen tasks, in context``; the label once where it names the
    tasks already (``8 validation tasks, in context``)."""
    what = f"{num_tasks} {tasks} tasks"
    return f"{env_id}: {what}{'' if label == f'{tasks} tasks' else f', {label}'}, in context"


def _add_to_model_card(model_dir: Path, results: dict) -> None:
    """Append a summary to the checkpoint's evaluations and re-render its card (model-index)."""
    prov_path = model_dir / TRAIN_CONFIG_FILE
    if not prov_path.exists():
        return  # not an lhf checkpoint folder (no card to update)
    with file_lock(
        model_dir / f".{MODEL_EVALS_FILE}.lock"
    ):  # concurrent evaluations: each entry kept
        _add_entry(model_dir, prov_path, results)


def _add_entry(model_dir: Path, prov_path: Path, results: dict) -> None:
    evals_path = model_dir / MODEL_EVALS_FILE
    evals = read_json(evals_path) if evals_path.exists() else []
    summary = {
        "out": str(Path(results["config"]["out"]).resolve()),
        "env_id": results["env_id"],
        "split_seed": results["split_seed"],
        "tasks": results["config"]["tasks"],
        "num_tasks": len(results["tasks"]),
        "task_label": results["task_label"],
        "episodes": results["config"]["episodes"],
        "rollouts": results["rollouts"],
        "plan": results["config"]["plan"],
        "plan_setting": plan_label(EvalConfig(**results["config"])).removeprefix(" + "),
        "seed": results["config"]["seed"],
        "context": results["context"],
        "mean_return": results["mean_return"],
        "final_return": results["final_return"],
        "success_rate": results["success_rate"],
    }
    evals = [e for e in evals if e["out"] != summary["out"]] + [summary]
    write_json_atomic(evals, evals_path)
    write_model_card(model_dir, AutoConfig.from_pretrained(model_dir), read_json(prov_path), evals)
