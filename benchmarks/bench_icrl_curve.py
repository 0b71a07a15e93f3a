"""In-context return against training wall time: how much a model learns per CPU-minute.

    python benchmarks/bench_icrl_curve.py --dataset data/dr50 [--objectives ad dpt dicp]
        [--minutes 15] [--every 2.5] [--episodes 50] [--seeds 0 1 2] [--lr 3e-3]
        [--steps N --every-steps M] [--train-seeds 0 1 2] [--plan] [--out results/train/icrl_curve]
        [--attention-kernel auto|kernel|torch] [--resume]

Trains each objective on ``--dataset`` (``lhf train``'s Trainer, the given settings) for
``--minutes`` of wall time, saving a checkpoint every ``--every`` minutes of training (a wall-clock
callback; the saves and the evaluations are not counted as training time).  The learning rate is
then ~constant (the cosine runs over 10^6 steps, since the clock sets the end).  With ``--steps N``
the run is instead a step budget, as a preset trains: the cosine decays to 0 over N steps, a
checkpoint every ``--every-steps``, and the training wall time of each is recorded.
``--train-seeds`` trains independent models (``TrainConfig.seed``: init, dropout, windows); the
plot's error bars are then the spread over trained models, otherwise over evaluation seeds.
``curve.json`` is rewritten after each model; ``--resume`` keeps the models it holds (measured with
the same settings; ``--train-seeds`` may add models) and trains only the missing ones.  Without it
an existing ``curve.json`` is an error, never overwritten.
Then every checkpoint
is evaluated in context on the validation goals of the dataset's split (``--tasks test
--report-on-test``: its test goals, to report a choice already made; test goals never choose one) (``--episodes`` episodes from an
empty context, one rollout per seed, each model with its own context semantics) and the mean return
of the last 10 episodes is plotted against the training minutes, with the published levels (DICP
paper, Darkroom: AD ~12.5, DICP ~15; issue 23's DPT target 14) as lines.  With ``--plan`` every DICP
checkpoint is also evaluated with planning (the same seeds, the learned dynamics): the DICP paper's
level 15 is DICP *with* planning, and whether planning helps depends on how far the model trained.  Writes ``curve.json`` and
``curve.png`` to ``--out``; the checkpoints go to a new folder under ``--work`` (nothing is deleted).
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from transformers import TrainerCallback

from lhf_hf.configs import TrainConfig
from lhf_hf.envs import get_spec
from lhf_hf.evaluation.rollout import rollout
from lhf_hf.evaluation.seen import TUNING_PARTS, check_unseen, tuning_tasks
from lhf_hf.evaluation.task_batch import make_task_batch
from lhf_hf.histories.reader import load_histories
from lhf_hf.modeling import load_model
from lhf_hf.training import build_trainer
from lhf_hf.training.trainer import RotateOwnCheckpoints
from lhf_hf.utils.io import save_figure_atomic, write_json_atomic
from lhf_hf.utils.outputs import OutputError, output_folder, preflight
from lhf_hf.utils.versions import library_versions

# Darkroom levels to reach: the DICP paper's AD and DICP at 50 episodes; issue 23's DPT target.
LEVELS = {"ad": 12.5, "dpt": 14.0, "dicp": 15.0}


class TrainingClock(TrainerCallback):
    """Training seconds (the optimiser steps only: saves and logging are not counted) and
    ``marks``: (step, training seconds) of every checkpoint saved."""

    def __init__(self):
        self.marks: list[tuple[int, float]] = []
        self.trained_s = 0.0
        self.t0 = None

    def on_step_begin(self, args, state, control, **kwargs):
        self.t0 = time.perf_counter()

    def on_step_end(self, args, state, control, **kwargs):
        self.trained_s += time.perf_counter() - self.t0

    def on_save(self, args, state, control, **kwargs):
        self.marks.append((state.global_step, self.trained_s))


class WallClockCheckpoints(TrainingClock):
    """Save every ``every_s`` seconds of training and stop after ``total_s``."""

    def __init__(self, every_s: float, total_s: float):
        super().__init__()
        self.every_s, self.total_s = every_s, total_s
        self.saves = 0

    def on_step_end(self, args, state, control, **kwargs):
        super().on_step_end(args, state, control, **kwargs)
        if self.trained_s >= self.every_s * (self.saves + 1) or self.trained_s >= self.total_s:
            control.should_save = True
            self.saves += 1
        if self.trained_s >= self.total_s:
            control.should_training_stop = True


def evaluate_checkpoint(
    path: Path, tasks, split_seed: int, episodes: int, seeds, plan: bool = False,
    plan_gate: str = "always",
) -> dict:  # fmt: skip
    model = load_model(str(path))
    last10, whole = [], []
    for seed in seeds:
        batch = make_task_batch(model.config.env_id, tasks, split_seed, seed)
        res = rollout(model, batch, episodes, seed=seed, plan=plan, progress=False,
                      plan_gate=plan_gate if plan else "always")  # fmt: skip
        last10.append(float(res.returns[:, -10:].mean()))
        whole.append(float(res.returns.mean()))
    return {"last10": last10, "whole_curve": whole, "context": res.context}


def _switch(k: str) -> str:
    """The flag spelling of an argparse dest: ``train_seeds`` -> ``--train-seeds``."""
    return f"--{k.replace('_', '-')}"


def _flag(k: str, v) -> str:
    """``--key value`` as a command line writes it (a list as its items)."""
    return f"{_switch(k)} {' '.join(map(str, v)) if isinstance(v, list) else v}"


def _command_flags(args: dict) -> str:
    """The flags that reproduce ``args`` (a switch is written only when it is on, an unset option
    not at all: ``--steps None`` would not parse back on ``--resume``)."""
    flags = []
    for k, v in args.items():
        if isinstance(v, bool):
            flags += [_switch(k)] if v else []
        elif v is not None:
            flags.append(_flag(k, v))
    return " ".join(flags)


def _measured(args) -> dict:
    """The flags that decide what a model measures: not where it is written, which models are
    trained (--train-seeds), or a mode's flags the other mode ignores."""
    ignored = {"train_seeds", "out", "work", "resume"}
    ignored |= {"minutes", "every"} if args.steps is not None else {"steps", "every_steps"}
    ignored |= set() if args.plan else {"plan_gate"}
    return {k: v for k, v in vars(args).items() if k not in ignored}


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--dataset", required=True)
    p.add_argument("--objectives", nargs="+", default=["ad", "dpt", "dicp"],
                   choices=["ad", "dpt", "dicp"])  # fmt: skip
    p.add_argument("--minutes", type=float, default=None,
                   help="a wall-clock budget of training minutes (default 15; not with --steps)")  # fmt: skip
    p.add_argument("--every", type=float, default=None,
                   help="minutes between checkpoints (default 2.5; not with --steps)")  # fmt: skip
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="evaluation seeds")
    p.add_argument("--train-seeds", type=int, nargs="+", default=[0],
                   help="one trained model per seed (TrainConfig.seed)")  # fmt: skip
    p.add_argument("--steps", type=int, default=None,
                   help="a step budget instead of --minutes: the cosine decays to 0 over it")  # fmt: skip
    p.add_argument("--every-steps", type=int, default=None,
                   help="steps between checkpoints with --steps (default: only the last)")  # fmt: skip
    p.add_argument("--lr", type=float, default=3e-3)
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--preset", default="paper")
    p.add_argument("--attention-kernel", default="auto", choices=["auto", "kernel", "torch"],
                   help="TrainConfig.attention_kernel: the training attention (a learning curve "
                        "of each, same seeds, shows they learn alike)")  # fmt: skip
    p.add_argument("--plan", action="store_true",
                   help="also evaluate DICP checkpoints with planning")  # fmt: skip
    p.add_argument("--plan-gate", default="always", choices=["always", "reward_seen"],
                   help="planning only for tasks whose context holds a reward (EvalConfig.plan_gate)")  # fmt: skip
    p.add_argument("--tasks", default="validation", choices=TUNING_PARTS,
                   help="the goals measured: validation (train on `lhf collect --tasks fit` "
                   "data), or test with --report-on-test")
    p.add_argument("--report-on-test", action="store_true",
                   help="allow --tasks test: reporting a choice already made, not making one")
    p.add_argument("--out", default="results/train/icrl_curve")
    p.add_argument("--work", default="runs/bench-icrl-curve")
    p.add_argument("--resume", action="store_true",
                   help="keep the models --out's curve.json holds (same settings; --train-seeds "
                        "may add models) and train the missing ones")  # fmt: skip
    args = p.parse_args()
    _check_flags(args)
    resume = args.resume
    del args.resume  # not part of what the results measure
    out = Path(args.out)
    objectives = {}
    if (out / "curve.json").exists() and not resume:
        raise SystemExit(
            f"error: {out / 'curve.json'} exists: pass --resume to keep its models and "
            "train the missing ones, or another --out"
        )
    try:  # before any training: a model is never trained only to find it cannot be written
        data = load_histories(args.dataset)
        env_id = data.env_id
        tuning_tasks(env_id, args.tasks, int(data.lhf["split_seed"]), args.report_on_test)
        for objective in args.objectives:  # the TrainConfig validates preset, lr, batch size
            _train_config(args, objective, 0, out="unused")
        _check_work(Path(args.work), args.dataset)
        preflight(out, "icrl-curve", resume=resume, inputs=[args.dataset], legacy=["curve.json"],
                  resumable=True)  # fmt: skip
    except (FileNotFoundError, ValueError, RuntimeError, OutputError) as exc:
        raise SystemExit(f"error: {exc}") from None
    if (out / "curve.json").exists():
        try:
            done = json.loads((out / "curve.json").read_text())
            recorded = p.parse_args(shlex.split(done["command"])[2:])
            objectives = done["objectives"]
            seeds = [r["train_seed"] for o in objectives.values() for r in o["runs"]]
        except (ValueError, KeyError, TypeError, AttributeError, SystemExit) as exc:
            raise SystemExit(
                f"error: --resume: {out / 'curve.json'} is not a curve.json of this benchmark "
                f"({type(exc).__name__}: {exc}); move it away or pick another --out"
            ) from None
        now = _measured(args)
        diff = {k: (v, now.get(k)) for k, v in _measured(recorded).items() if now.get(k) != v}
        if diff:
            shown = ", ".join(f"{_flag(k, a)} (now {_flag(k, b)})" for k, (a, b) in diff.items())
            raise SystemExit(
                f"error: --resume: {out / 'curve.json'} was measured with other settings: {shown}"
            )
        # the record's command names every model it holds
        args.train_seeds = list(dict.fromkeys([*seeds, *args.train_seeds]))
    results = {
        "command": "python benchmarks/bench_icrl_curve.py " + _command_flags(vars(args)),
        "machine": platform.processor() or platform.machine(),
        "torch_threads": torch.get_num_threads(),
        "versions": library_versions(["torch", "transformers"]),
        "env_id": env_id,
        "levels": LEVELS if env_id == "darkroom" else {},  # published levels: Darkroom only
        "objectives": objectives,
    }
    with output_folder(out, "icrl-curve", resume=resume, inputs=[args.dataset],
                       legacy=["curve.json"], resumable=True):  # fmt: skip
        for train_seed in args.train_seeds:  # seed-major: every objective's first model first
            for objective in args.objectives:
                runs = results["objectives"].get(objective, {}).get("runs", [])
                if any(r["train_seed"] == train_seed for r in runs):
                    print(f"{objective} train seed {train_seed}: in {out / 'curve.json'} already")
                    continue
                run = {"train_seed": train_seed, **train_and_evaluate(args, objective, train_seed)}
                entry = results["objectives"].setdefault(
                    objective, {"tasks": run["tasks"], "runs": []}
                )
                entry["runs"].append(run)
                # after each model, the record and its plot: an interrupt loses no model
                write_json_atomic(results, out / "curve.json")
                plot(results, out / "curve.png", args.episodes)
        if not (out / "curve.png").exists():  # every model was recorded already: re-plot
            plot(results, out / "curve.png", args.episodes)


def _check_flags(args) -> None:
    """Flags that contradict each other, or a value out of range: an error before any work."""
    if args.steps is None:
        args.minutes = 15.0 if args.minutes is None else args.minutes
        args.every = 2.5 if args.every is None else args.every
        if args.every <= 0 or args.minutes < args.every:
            raise SystemExit("error: need 0 < --every <= --minutes")
        if args.every_steps is not None:
            raise SystemExit("error: --every-steps goes with --steps")
    else:
        if args.minutes is not None or args.every is not None:
            raise SystemExit(
                "error: --minutes and --every are a wall-clock budget: not with --steps"
            )
        every = args.steps if args.every_steps is None else args.every_steps
        if args.steps < 1 or not 1 <= every <= args.steps:
            raise SystemExit("error: need --steps >= 1 and 1 <= --every-steps <= --steps")
        if args.steps % every:  # the Trainer saves at multiples only
            raise SystemExit("error: --every-steps must divide --steps (the last step is saved)")
    if args.episodes < 1:
        raise SystemExit("error: need --episodes >= 1 (the curve's return is over the episodes)")
    if args.plan and "dicp" not in args.objectives:
        raise SystemExit("error: --plan evaluates DICP checkpoints: add dicp to --objectives")
    if args.plan_gate != "always" and not args.plan:
        raise SystemExit("error: --plan-gate applies to planning: add --plan")


def _check_work(work: Path, dataset: str) -> None:
    """The checkpoints go to new folders under ``work``: never inside the dataset (they would be
    files the dataset's manifest does not know, and ``lhf verify`` would fail)."""
    if work.exists() and not work.is_dir():
        raise OutputError(f"--work {work} is a file, not a folder")
    src = Path(dataset)
    if src.exists() and (
        work.resolve() == src.resolve() or src.resolve() in work.resolve().parents
    ):
        raise OutputError(f"--work {work} is inside the dataset {dataset}: choose another folder")


def _train_config(args, objective: str, train_seed: int, out: str) -> TrainConfig:
    if args.steps is None:  # a wall-clock budget: the cosine's end is out of reach (~constant lr)
        max_steps, save_steps = 10**6, 10**9
    else:
        max_steps, save_steps = args.steps, args.every_steps or args.steps
    return TrainConfig(dataset=args.dataset, objective=objective, out=out, preset=args.preset,
                       max_steps=max_steps, batch_size=args.batch_size, lr=args.lr,
                       save_steps=save_steps, logging_steps=100, seed=train_seed,
                       attention_kernel=args.attention_kernel)  # fmt: skip


def train_and_evaluate(args, objective: str, train_seed: int) -> dict:
    Path(args.work).mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f"{objective}-", dir=args.work))  # new, never reused
    if args.steps is None:
        clock = WallClockCheckpoints(args.every * 60, args.minutes * 60)
    else:
        clock = TrainingClock()
    try:
        trainer, provenance = build_trainer(_train_config(args, objective, train_seed, str(work)))
        trainer.add_callback(clock)
        trainer.args.disable_tqdm = True
        trainer.remove_callback(RotateOwnCheckpoints)  # every checkpoint is evaluated
        trainer.train()
    except BaseException:
        if not any(work.iterdir()):
            work.rmdir()  # our own folder, still empty: leave nothing behind
        raise
    split_seed = int(provenance["dataset"]["split_seed"])
    env_id = provenance["dataset"]["env_id"]
    tasks = tuning_tasks(env_id, args.tasks, split_seed, args.report_on_test)
    # a dataset holding these tasks would measure trained goals: refused, as by lhf evaluate
    check_unseen(get_spec(env_id), trainer.model.config, tasks, split_seed, False, str(work))
    points = []
    for step, trained_s in clock.marks:
        ev = evaluate_checkpoint(work / f"checkpoint-{step}", tasks, split_seed,
                                 args.episodes, args.seeds)  # fmt: skip
        if args.plan and objective == "dicp":
            ev["plan"] = evaluate_checkpoint(work / f"checkpoint-{step}", tasks, split_seed,
                                             args.episodes, args.seeds, plan=True,
                                             plan_gate=args.plan_gate)  # fmt: skip
        points.append({"step": step, "minutes": round(trained_s / 60, 2), **ev})
        print(objective, f"train seed {train_seed}", points[-1], flush=True)
    return {"tasks": tasks, "points": points}


def plot(results: dict, path: Path, episodes: int) -> None:
    import matplotlib  # deferred: only the plot needs it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: see above

    fig, ax = plt.subplots(figsize=(6, 4))
    for i, (objective, r) in enumerate(results["objectives"].items()):
        colour = f"C{i}"
        runs = r["runs"]
        n = min(len(run["points"]) for run in runs)  # checkpoints every run reached
        x = np.mean([[pt["minutes"] for pt in run["points"][:n]] for run in runs], axis=0)  # (n,)
        for key, style, label in (("last10", "-", ""), ("plan", ":", " + plan")):
            if key == "plan" and not all("plan" in pt for run in runs for pt in run["points"]):
                continue  # DICP with planning, same checkpoints, when it was evaluated
            # (runs, n, eval seeds): a trained model's return per evaluation seed
            y = np.array([[(pt[key]["last10"] if key == "plan" else pt[key])
                           for pt in run["points"][:n]] for run in runs])  # fmt: skip
            # error bars: the spread over trained models where there are several, else over seeds
            spread = y.mean(2).std(0) if len(runs) > 1 else y[0].std(1)
            ax.errorbar(x, y.mean((0, 2)), yerr=spread, color=colour, ls=style,
                        marker="s" if key == "plan" else "o", capsize=3,
                        label=objective.upper() + label)  # fmt: skip
        if objective in results["levels"]:
            ax.axhline(results["levels"][objective], color=colour, ls="--", lw=0.8)
    ax.set_xlabel(f"training wall time (minutes, {results['torch_threads']} torch threads)")
    ax.set_ylabel(f"return, episodes {max(1, episodes - 9)}-{episodes} (unseen goals)")
    levels = " (dashed: published levels)" if results["levels"] else ""
    ax.set_title(
        f"{results.get('env_id', 'darkroom')}: in-context return per training minute{levels}"
    )
    ax.legend()
    fig.tight_layout()
    fig.set_dpi(120)  # savefig's default dpi is the figure's
    save_figure_atomic(fig, path)


if __name__ == "__main__":
    main()
