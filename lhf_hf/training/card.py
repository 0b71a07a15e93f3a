"""Model card (README.md from ``lhf_hf/templates/model_card.md``) and the loss plot of a checkpoint."""

from __future__ import annotations

import json
import shlex
from pathlib import Path, PurePosixPath

from huggingface_hub import EvalResult, ModelCard, ModelCardData

from lhf_hf.envs import split_part
from lhf_hf.utils.hub import public_source
from lhf_hf.utils.io import save_figure_atomic, write_text_atomic
from lhf_hf.utils.templates import template_path

MODEL_EVALS_FILE = "evaluations.json"  # in the checkpoint: every evaluation, rendered in its card

OBJECTIVE_NAMES = {
    "ad": "Algorithm Distillation (AD)",
    "dpt": "Decision-Pretrained Transformer (DPT)",
    "dicp": "Distillation for In-Context Planning (DICP)",
}
NO_EVAL = "Not evaluated yet: the `lhf evaluate` command above runs the paper's evaluation."


def plot_loss(log_history: list[dict], path: Path) -> None:
    import matplotlib  # deferred: 0.5 s, paid only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: after matplotlib.use("Agg")

    rows = [r for r in log_history if "loss" in r]
    fig, ax = plt.subplots(figsize=(6, 3.4), dpi=120)
    if rows:
        ax.plot([r["step"] for r in rows], [r["loss"] for r in rows], label="loss")
        ax.legend(fontsize=8)
    ax.set_xlabel("optimiser step")
    ax.set_ylabel("training loss")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure_atomic(fig, path)


#: What every entry of a model's evaluations list holds (the card's row and model-index use them).
EVAL_ENTRY_KEYS = frozenset(
    {"out", "env_id", "num_tasks", "tasks", "split_seed", "episodes", "plan", "mean_return",
     "final_return"}
)  # fmt: skip


def evaluation_problems(evals) -> list[str]:
    """Why ``evals`` (a model's ``evaluations.json``) is not a list of evaluation entries."""
    if not isinstance(evals, list):
        return ["is not a list of evaluations"]
    for i, e in enumerate(evals):
        if not isinstance(e, dict):
            return [f"entry {i} is not an object"]
        missing = sorted(EVAL_ENTRY_KEYS - set(e))
        if missing:
            return [f"entry {i} lacks {', '.join(missing)}"]
    return []


def eval_section(evaluations: list[dict]) -> str:
    if not evaluations:
        return NO_EVAL
    lines = [
        "In-context returns (mean over tasks, and over rollouts where a task was rolled out "
        "`x N` times; whole curve and the last 10% of the episodes), from `lhf evaluate`; "
        "the seen column says whether the model trained on the tasks:",
        "",
        "| env | tasks | seen | split seed | seed | episodes | planning | context | mean return | final return | success |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for e in evaluations:
        succ = "-" if e.get("success_rate") is None else f"{e['success_rate']:.3f}"
        lines.append(
            f"| {e['env_id']} | {e['num_tasks']} {e['tasks']}{_copies(e)} | {e.get('task_label', '-')} | {e['split_seed']} | {e.get('seed', '-')} | {e['episodes']} | "
            f"{_planning(e)} | {e.get('context', '-')} | {e['mean_return']:.3f} | "
            f"{e['final_return']:.3f} | {succ} |"
        )
    return "\n".join(lines)


def is_seen(e: dict) -> bool:
    """Whether an evaluation (its results or its card entry) is on tasks the model trained on:
    its ``task_label`` starts with "seen tasks" (``lhf_hf.evaluation.seen.seen_label``; the
    others are "unseen tasks" and "validation tasks")."""
    return e.get("task_label", "unseen tasks").startswith("seen tasks")


def model_index(evaluations: list[dict]) -> list:
    """One model-index result per evaluation.  The Hub groups results by task and dataset (type,
    config, split), keeping the first group's dataset name: the task set and split go in the
    dataset config, so evaluations on other splits stay apart, and what else tells evaluations of
    one split apart (seed, rollouts, planning, context) goes in the metric's name."""
    out = []
    for e in evaluations:
        setting = [f"seed {e['seed']}"] if "seed" in e else []
        if e.get("rollouts", 1) > 1:
            setting.append(f"{e['rollouts']} rollouts per task")
        if e["plan"]:
            setting.append(e.get("plan_setting") or "planning")
        if e.get("context"):
            setting.append(f"context {e['context']}")
        episodes = f"mean return over {e['episodes']} episode{'s' * (e['episodes'] > 1)}"
        out.append(
            EvalResult(
                task_type="reinforcement-learning",
                task_name="in-context reinforcement learning",
                dataset_type=e["env_id"],
                dataset_name=f"{e['env_id']} ({e['tasks']} tasks, split {e['split_seed']}"
                + (f", {e['task_label']})" if is_seen(e) else ")"),
                dataset_config=f"{e['tasks']}-split-{e['split_seed']}"
                + ("-seen" if is_seen(e) else ""),
                metric_type="mean_reward",
                metric_name=f"{episodes} ({', '.join(setting)})" if setting else episodes,
                metric_value=round(e["mean_return"], 4),
            )
        )
    return out


def render_model_card(
    config,
    provenance: dict,
    load_path: str,
    evaluations: list[dict] | None = None,
    public: bool = False,
) -> str:
    """The card's text; ``load_path``: what its snippets load (the folder, or the repo id);
    ``public``: for a push (the dataset and selection by name, never a path of this machine)."""

    def source(path: str, what: str = "dataset") -> str:
        return public_source(path, what) if public else f"`{path}`"

    train = provenance["train"]
    ds = provenance["dataset"]
    sel = provenance.get("selection")
    params = provenance.get("parameters")
    card_data = ModelCardData(
        library_name="transformers",
        license="apache-2.0",
        tags=["lhf_hf", "in-context-rl", "reinforcement-learning", config.objective, ds["env_id"]],
        pipeline_tag="reinforcement-learning",
    )
    model_name = f"{config.objective.upper()} on {ds['env_id']}" + (" with LHF" if sel else "")
    eval_out = shlex.quote(f"{PurePosixPath(load_path).name}-eval")  # beside where it is run
    split_seed = config.split_seed if config.split_seed is not None else 0
    tasks, tasks_note, eval_flags = _rollout_tasks(config, ds["env_id"], split_seed)
    if evaluations:
        card_data.model_name = model_name
        card_data.eval_results = model_index(evaluations)
    return ModelCard.from_template(
        card_data,
        template_path=str(template_path("model_card.md")),
        model_name=model_name,
        objective_name=OBJECTIVE_NAMES[config.objective],
        objective=config.objective,
        env_id=ds["env_id"],
        selection_phrase=" resampled by an LHF selection" if sel else "",
        layers=_count(config.num_hidden_layers, "layer"),
        heads=_count(config.num_attention_heads, "head"),
        hidden=config.hidden_size,
        intermediate=config.intermediate_size,
        params=f"{params:,}" if params else "?",
        context_length=config.context_length,
        tokens=config.max_tokens,
        load_path_py=json.dumps(load_path),  # a Python string literal
        split_seed=split_seed,
        tasks=tasks,
        tasks_note=tasks_note,
        eval_out=eval_out,
        evaluate_command=" ".join(
            ["lhf evaluate --model", shlex.quote(load_path), "--out", eval_out, *eval_flags]
        ),
        label_positions=config.label_positions,
        xi_phrase=(
            f", xi = {config.dynamics_coef}, reward loss weighting '{config.reward_weighting}'"
            if config.objective == "dicp"
            else ""
        ),
        dataset_source=source(ds["path"]),
        dataset_fingerprint=ds["fingerprint"][:16],
        selection_text=(
            f"{source(sel['path'], 'selection')} ({sel['filter']['strategy']}, lambda "
            f"{sel['filter']['lam']}; "
            f"{sel['selected_unique']} histories kept)"
            if sel
            else "none (every history once)"
        ),
        max_steps=train["max_steps"],
        batch_size=train["batch_size"],
        items=(
            f"sequences of {provenance['sequence_length']} transitions, band attention over "
            f"the last {config.context_length}"
            if provenance.get("sequence_length")
            else "windows"
        ),
        processes=_count(provenance.get("world_size", 1), "process", "processes"),
        beta1=train["beta1"],
        beta2=train["beta2"],
        lr=train["lr"],
        weight_decay=train["weight_decay"],
        # the template's optimiser row ends with the clip: the other Trainer arguments follow it
        max_grad_norm=f"{train['max_grad_norm']}{_other_arguments(train)}",
        seed=train["seed"],
        final_loss=_final_loss(provenance),
        runtime=provenance.get("train_runtime_s", "-"),
        versions=", ".join(f"{k} {v}" for k, v in provenance.get("versions", {}).items()),
        eval_section=eval_section(evaluations or []),
    ).content


def _count(n: int, one: str, many: str | None = None) -> str:
    return f"{n} {one if n == 1 else many or one + 's'}"


def _final_loss(provenance: dict) -> str:
    """The last logged loss; a run shorter than its logging interval logs none, and then the
    card gives Trainer's mean loss over the run (``train_loss``), saying so."""
    if provenance.get("final_loss") is not None:
        return f"{provenance['final_loss']:.4f}"
    mean = (provenance.get("metrics") or {}).get("train_loss")
    every = provenance.get("train", {}).get("logging_steps")
    why = f"none logged: --logging-steps {every} is past the run's end" if every else "none logged"
    return f"- ({why}; mean over the run {mean:.4f})" if mean is not None else f"- ({why})"


def _rollout_tasks(config, env_id: str, split_seed: int) -> tuple[str, str, list[str]]:
    """(the card's Python expression for the rollout's tasks, what they are, ``lhf evaluate``
    flags): the test tasks of the model's split that it did not train on, which ``lhf evaluate``
    accepts as they are (``evaluation.seen``); where none is left, or the model does not record
    its training tasks, the test tasks, which ``lhf evaluate`` reports as seen (``--allow-seen``)."""
    test = split_part(env_id, "test", split_seed)
    expr = f'split_part("{env_id}", "test", {split_seed})'
    trained = config.train_tasks
    if trained is None:
        note = f"the test tasks of split {split_seed} (which tasks it trained on is not recorded)"
        return expr, note, ["--allow-seen"]
    unseen = [t for t in test if t not in set(trained)]
    if len(unseen) == len(test):
        return expr, f"the test tasks of split {split_seed}, unseen in training", []
    if unseen:
        return (
            f"[t for t in {expr} if t not in model.config.train_tasks]",
            f"the test tasks of split {split_seed} but the {len(test) - len(unseen)} it trained on",
            ["--tasks", ",".join(map(str, unseen))],
        )
    return expr, f"the test tasks of split {split_seed}: it trained on every one", ["--allow-seen"]


def write_model_card(
    out: Path, config, provenance: dict, evaluations: list[dict] | None = None
) -> Path:
    text = render_model_card(
        config, provenance, load_path=str(Path(out).resolve()), evaluations=evaluations
    )
    write_text_atomic(text, Path(out) / "README.md")
    return Path(out) / "README.md"


def _other_arguments(train: dict) -> str:
    """'; TrainingArguments also set: k=v, ...' for ``--training-arg`` (none: '')."""
    given = train.get("training_args") or {}
    if not given:
        return ""
    return "; TrainingArguments also set: " + ", ".join(f"`{k}={v!r}`" for k, v in given.items())


def _copies(e: dict) -> str:
    """' x N' for an evaluation that rolled each task out N times (``EvalConfig.rollouts``)."""
    n = e.get("rollouts", 1)
    return f" x {n}" if n > 1 else ""


def _planning(e: dict) -> str:
    """The card's planning column: no / yes / yes and how it deviates (gate, dynamics, order)."""
    if not e["plan"]:
        return "no"
    how = e.get("plan_setting", "planning").removeprefix("planning")
    return "yes" + how
