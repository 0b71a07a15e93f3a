"""``train(cfg)``: pretrain an AD / DPT / DICP model with ``transformers.Trainer`` (docs/design.md 6).

Runs as is (one process) or under ``accelerate launch`` (CPU data parallel with the shipped
``lhf_hf/launch/cpu_2proc.yaml``, ``lhf accelerate-config``): the global batch is split across processes and the model's
``accepts_loss_kwargs = False`` keeps the logged loss on the same scale as one process.
"""

from __future__ import annotations

import os
import re
import shutil
import sys
import time
from contextlib import ExitStack
from pathlib import Path

import torch
from huggingface_hub import CommitOperationAdd, HfApi
from transformers import Trainer, TrainerCallback, set_seed
from transformers.trainer_utils import PREFIX_CHECKPOINT_DIR

from lhf_hf import constants as C
from lhf_hf.configs.train import TrainConfig
from lhf_hf.envs import get_spec
from lhf_hf.errors import NotFoundError, UserError
from lhf_hf.filtering.counts import selection_counts
from lhf_hf.histories import load_histories
from lhf_hf.modeling import MODEL_CODE_FILES, ICRLConfig, ICRLModel, save_model_code
from lhf_hf.modeling.loading import check_weights
from lhf_hf.utils.hub import HubError, endpoint, error_text, public_contents, require_token
from lhf_hf.utils.io import (
    give_umask_mode,
    read_json,
    write_json_atomic,
    write_text_atomic,
)
from lhf_hf.utils.launcher import end_ranks
from lhf_hf.utils.outputs import output_folder
from lhf_hf.utils.progress import library_bars
from lhf_hf.utils.versions import library_versions

from .arguments import refused, resolve, training_arguments
from .attention_backend import resolve_attention_kernel, use_attention
from .card import MODEL_EVALS_FILE, plot_loss, write_model_card
from .collators import make_collator
from .model_config import (
    check_model_env,
    describe_coverage,
    model_config_for,
    sequence_length,
    split_coverage,
)
from .windows import WindowDataset, load_arrays

TRAIN_CONFIG_FILE = "train_config.json"
#: Trainer's arguments as JSON: Trainer itself pickles them into ``training_args.bin``, and loading a
#: pickle runs code, so no folder of ours keeps one (see ``WindowTrainer._save``).
TRAINING_ARGS_FILE = "training_args.json"
#: In every checkpoint: what produced it (``train_identity``), checked by ``--resume``.
IDENTITY_FILE = "lhf_train_identity.json"
#: TrainConfig fields that decide what a step computes (logging, saving and places do not).
_IDENTITY_FIELDS = ("objective", "preset", "context_length", "label_positions", "lr",
                    "warmup_steps", "weight_decay", "beta1", "beta2", "max_grad_norm",
                    "dynamics_coef", "seed", "batch_size", "max_steps",
                    "state_encoding", "attention", "sequence_length", "reward_weighting",
                    "training_args", "attention_kernel")  # fmt: skip
_MODEL_FIELDS = ("objective", "state_dim", "state_bins", "state_encoding", "attention", "action_dim",
                 "discrete_actions",
                 "context_length", "label_positions", "hidden_size", "intermediate_size",
                 "num_hidden_layers", "num_attention_heads", "dynamics_coef",
                 "reward_weighting")  # fmt: skip
#: What identities written before a field existed mean by its absence.
#: (attention_kernel: runs before the field trained with the torch path, ``lhf_sdpa``.)
_BEFORE_FIELD = {"reward_weighting": "data", "training_args": {}, "attention_kernel": "torch"}
PICKLED_TRAINING_ARGS = "training_args.bin"
LOG_FILE = "training_log.json"
LOSS_PLOT = "training_loss.png"
# Draws per sampler pass: sampling with replacement keeps the sampler's memory bounded on datasets
# with hundreds of millions of windows (a permutation of all of them would not fit).
MAX_SAMPLER_DRAWS = 1 << 24


class WindowTrainer(Trainer):
    """Trainer that draws windows uniformly with replacement (every history copy equally often).

    The model card is ours (``train`` writes it, and pushes the finished folder with it), so
    Trainer's generic card is never written.
    """

    def create_model_card(self, *args, **kwargs):
        return None

    def _save(self, output_dir: str | None = None, state_dict=None):
        """Trainer's save (weights, config), with the model's code beside them (so that
        transformers alone loads the folder) and the training arguments as JSON, not a pickle."""
        out = Path(output_dir if output_dir is not None else self.args.output_dir)
        if self.args.should_save:  # the code first: config.json's auto_map names its files
            save_model_code(out, self.model.config)
        super()._save(output_dir, state_dict)
        if self.args.should_save:
            for weights in out.glob("model*.safetensors"):  # 0600 from safetensors: the umask's
                give_umask_mode(weights)
            (out / PICKLED_TRAINING_ARGS).unlink(missing_ok=True)
            write_text_atomic(self.args.to_json_string(), out / TRAINING_ARGS_FILE)
            identity = getattr(self, "lhf_identity", None)
            if identity is not None and out.name.startswith("checkpoint-"):
                write_json_atomic(identity, out / IDENTITY_FILE)

    def _get_train_sampler(self, train_dataset=None):
        ds = train_dataset if train_dataset is not None else self.train_dataset
        # A whole number of global batches per pass: every step sees the batch size asked for
        # (a pass ending in a short batch would give some steps fewer windows).
        batch = self.args.per_device_train_batch_size * self.args.world_size
        draws = max(batch, min(len(ds), MAX_SAMPLER_DRAWS) // batch * batch)
        return torch.utils.data.RandomSampler(ds, replacement=True, num_samples=draws)


class _PushCheckpoints(TrainerCallback):
    """Pushes each saved checkpoint's weights, config, model code and arguments (JSON, without
    local paths) to the model repo.

    Trainer's own ``hub_strategy="every_save"`` would upload the output folder with the pickled
    ``training_args.bin`` in it; this pushes the same files as one commit per save ("Training in
    progress, step N"), blocking, so a failed push stops training with the Hub's error.
    """

    FILES = ["config.json", "model.safetensors", TRAINING_ARGS_FILE, *MODEL_CODE_FILES]

    def on_save(self, args, state, control, **kwargs):
        if not state.is_world_process_zero:
            return
        folder = Path(args.output_dir) / f"checkpoint-{state.global_step}"
        files = [name for name in self.FILES if (folder / name).is_file()]
        public = public_contents(folder, files)  # as `lhf push` uploads them: no local paths
        # Trainer's saving turns huggingface_hub's bars back on (transformers'
        # suppress_progress_bars re-enables them on exit): --no-progress is applied again here
        with library_bars(not args.disable_tqdm):
            HfApi().create_commit(
                repo_id=args.hub_model_id,
                operations=[CommitOperationAdd(f, public.get(f, str(folder / f))) for f in files],
                commit_message=f"Training in progress, step {state.global_step}",
                token=args.hub_token,
                revision=args.hub_revision,
            )


#: What Trainer and ``WindowTrainer._save`` write into a checkpoint: the only files rotation deletes.
CHECKPOINT_FILES = re.compile(
    r"^(config\.json|model.*\.safetensors|optimizer\.pt|scheduler\.pt|rng_state(_\d+)?\.pth|"
    r"trainer_state\.json|training_args\.(json|bin)|lhf_train_identity\.json|"
    r"generation_config\.json|scaler\.pt|" + "|".join(map(re.escape, MODEL_CODE_FILES)) + r")$"
)
KEEP_CHECKPOINTS = 2


class RotateOwnCheckpoints(TrainerCallback):
    """Keeps the newest ``KEEP_CHECKPOINTS`` checkpoints, as Trainer's ``save_total_limit`` would,
    but never deletes one holding anything Trainer did not write (a user's notes, an evaluation
    ``--out CKPT/eval``): that one stays, and is named once."""

    def __init__(self) -> None:
        self.kept: set[str] = set()

    def on_save(self, args, state, control, **kwargs):
        if not state.is_world_process_zero:
            return
        numbered = sorted(
            (int(p.name.split("-", 1)[1]), p)
            for p in Path(args.output_dir).glob(f"{PREFIX_CHECKPOINT_DIR}-*")
            if p.is_dir() and p.name.split("-", 1)[1].isdigit()
        )
        for _, path in numbered[:-KEEP_CHECKPOINTS]:
            foreign = [e.name for e in path.iterdir() if not CHECKPOINT_FILES.match(e.name)]
            if not foreign:
                shutil.rmtree(path, ignore_errors=True)
            elif str(path) not in self.kept:
                self.kept.add(str(path))
                print(
                    f"lhf: note: {path} is kept (it holds {', '.join(sorted(foreign)[:4])}, "
                    "which training did not write)",
                    file=sys.stderr,
                )


class _Throughput(TrainerCallback):
    """Logs windows/s and tokens/s beside the loss."""

    def __init__(self, tokens_per_step: int):
        self.tokens_per_step = tokens_per_step
        self.t0 = None
        self.step0 = 0

    def on_train_begin(self, args, state, control, **kwargs):
        self.t0, self.step0 = time.perf_counter(), state.global_step

    def on_log(self, args, state, control, logs=None, **kwargs):
        if logs is not None and self.t0 is not None and state.global_step > self.step0:
            dt = time.perf_counter() - self.t0
            logs["tokens_per_s"] = round(
                self.tokens_per_step * (state.global_step - self.step0) / dt, 1
            )


# ---------------------------------------------------------------------------- train
def build_trainer(cfg: TrainConfig, model_config: ICRLConfig | None = None, progress: bool = True):
    """Everything ``train`` runs, without running it: (trainer, provenance dict)."""
    cfg = resolve(cfg)  # reporters and other Trainer arguments, before the data loads
    ds = load_histories(cfg.dataset)
    spec = get_spec(ds.env_id)
    has_optimal = C.OPTIMAL_ACTION in ds.info.get("features", {})
    config = model_config or model_config_for(spec, cfg, has_optimal)
    check_model_env(config, spec)
    # What the model saw, in its config (so every checkpoint-N carries it): evaluation refuses
    # these tasks as "unseen" (they are not), and takes its default split from here.
    split_seed = int(ds.lhf.get("split_seed", 0))
    data_tasks = sorted({int(t) for t in ds.histories.data.table.column(C.TASK_ID).to_pylist()})
    config.train_tasks, config.split_seed = data_tasks, split_seed
    if config.objective != cfg.objective:
        raise UserError(
            f"model objective {config.objective!r} != train objective {cfg.objective!r}"
        )
    arrays = load_arrays(
        ds, integer_states=config.state_bins > 0, discrete_actions=config.discrete_actions
    )
    counts, selection = None, None
    if cfg.selection:
        counts, selection = selection_counts(cfg.selection, ds, arrays.history_index)
    length = sequence_length(cfg, config)
    shortest = int(arrays.history_lengths.min())
    if config.context_length <= shortest < length:  # band sequences only: windows are checked below
        default = " (the default: 4 x the context)" if cfg.sequence_length is None else ""
        raise UserError(
            f"band-attention sequences of {length} transitions{default} are longer than the "
            f"shortest history ({shortest} transitions): pass a --sequence-length between "
            f"{config.context_length} and {shortest}"
        )
    windows = WindowDataset(arrays, length, counts)
    if cfg.batch_size > len(windows):
        raise UserError(
            f"--batch-size {cfg.batch_size} is larger than the {len(windows)} training windows of "
            f"{length} transitions in {cfg.dataset}: pass --batch-size {len(windows)} or less, or "
            "a shorter --context-length"
        )
    collator = make_collator(arrays, config, length)

    # The launcher's WORLD_SIZE, read before TrainingArguments sets up the process group (a bare
    # PartialState() here would initialise accelerate's shared state as non-distributed on CPU).
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if cfg.batch_size % world:
        raise UserError(f"--batch-size {cfg.batch_size} is not divisible by the {world} processes")
    set_seed(cfg.seed)
    model = ICRLModel(config)
    args = training_arguments(cfg, world, progress)
    if args.world_size != world:
        raise RuntimeError(f"expected {world} processes, accelerate set up {args.world_size}")
    attention_backend = resolve_attention_kernel(cfg, config, args.device)
    use_attention(model, attention_backend)
    try:
        trainer = WindowTrainer(
            model=model,
            args=args,
            train_dataset=windows,
            data_collator=collator,
            callbacks=[
                _Throughput(cfg.batch_size * length * config.tokens_per_transition),
                RotateOwnCheckpoints(),
            ]
            + ([_PushCheckpoints()] if cfg.push_to_hub else []),
        )
    except ValueError as exc:  # Trainer's checks of its arguments
        if not cfg.training_args:
            raise
        raise refused(cfg, "Trainer", exc) from None
    except Exception as exc:  # noqa: BLE001 (the Hub's HTTP and connection errors, whatever class)
        # Trainer creates the --push-to-hub repo in its __init__: a refusal there is one line
        if not cfg.push_to_hub or not _from_the_hub(exc):
            raise
        raise HubError(
            f"--push-to-hub {cfg.push_to_hub}: the repo could not be created on {endpoint()} "
            f"(nothing was trained): {error_text(exc)}"
        ) from None
    provenance = {
        "train": _recorded_paths(cfg.to_dict()),
        "dataset": {
            "path": ds.source,
            "env_id": ds.env_id,
            "split_seed": split_seed,
            "tasks": data_tasks,
            "split_coverage": split_coverage(spec, data_tasks, split_seed),
            "fingerprint": ds.fingerprint,
            # the same histories before ``lhf upgrade`` rewrote their layout (resumable across it)
            "upgraded_from": (ds.lhf.get("upgraded") or {}).get("fingerprint"),
            "total_histories": int(arrays.num_histories),
            "total_frames": int(len(arrays.rewards)),
        },
        "selection": selection,
        "windows": len(windows),
        "sequence_length": length if config.attention == "band" else None,
        "reward_weighting": config.reward_weighting,  # resolved (``train`` keeps the flag as given)
        "attention_kernel": attention_backend,  # resolved: kernel or torch (their masks differ)
        "world_size": world,
        "world_sizes": [[0, world]],  # with resumes at other world sizes: [first step, processes]
        "per_device_batch_size": cfg.batch_size // world,
    }
    trainer.lhf_identity = train_identity(cfg, config, provenance)
    return trainer, provenance


def _recorded_paths(train: dict) -> dict:
    """The train config as recorded: its local folders absolute (a relative path means nothing
    away from where the command ran, and a push reduces an absolute one to ``local:NAME``); a Hub
    repo id stays as given."""
    out = dict(train)
    for key in ("dataset", "selection", "out"):
        if out.get(key) and Path(out[key]).exists():
            out[key] = str(Path(out[key]).resolve())
    return out


def _from_the_hub(exc: BaseException) -> bool:
    """An error of the Hub client or its HTTP stack (the repo creation Trainer runs)."""
    return any(
        c.__module__.split(".")[0] in ("huggingface_hub", "httpx", "httpcore", "requests")
        for c in type(exc).__mro__
    )


def train_identity(cfg: TrainConfig, config: ICRLConfig, provenance: dict) -> dict:
    """What a training run's steps depend on: the data (fingerprints), the model and the
    optimisation settings.  A resumed run must match the checkpoint's."""
    selection = provenance.get("selection") or {}
    return {
        # the resolved sequence length and reward weighting: an unset one and its default are the
        # same run
        "train": {k: getattr(cfg, k) for k in _IDENTITY_FIELDS}
        | {
            "sequence_length": provenance.get("sequence_length"),
            "reward_weighting": config.reward_weighting,
            # the code that ran, not the flag: auto and what it chose are the same run
            "attention_kernel": provenance.get("attention_kernel", "torch"),
        },
        "model": {k: getattr(config, k) for k in _MODEL_FIELDS},
        "dataset_fingerprint": provenance["dataset"]["fingerprint"],
        "dataset_upgraded_from": provenance["dataset"].get("upgraded_from"),
        "selection_fingerprint": selection.get("counts_sha256"),
        # [first step, processes] of each stretch of the run (not compared by --resume: the
        # global batch is the same at any world size; recorded so a resumed run says how it ran)
        "world_sizes": [[0, provenance["world_size"]]],
    }


def check_resume(checkpoint: str, identity: dict) -> None:
    """Refuse to resume ``checkpoint`` with another dataset, selection, model or settings."""
    path = Path(checkpoint) / IDENTITY_FILE
    if not path.exists():
        raise UserError(
            f"--resume: {checkpoint} does not record what it was trained with ({IDENTITY_FILE}), "
            "so resuming it cannot be checked; train afresh with --overwrite"
        )
    old = read_json(path)
    diff = []
    for part in ("train", "model"):
        for k in sorted(set(old.get(part, {})) | set(identity[part])):
            # a checkpoint from before a field existed was trained as its old behaviour
            a, b = old.get(part, {}).get(k, _BEFORE_FIELD.get(k)), identity[part].get(k)
            line = f"{k}: {a!r} -> {b!r}"
            if a != b and line not in diff:  # objective etc. are in both parts: named once
                diff.append(line)
    for k in ("dataset_fingerprint", "selection_fingerprint"):
        before = identity.get("dataset_upgraded_from")  # the data's fingerprint before lhf upgrade
        upgraded = k == "dataset_fingerprint" and before is not None and old.get(k) == before
        if old.get(k) != identity[k] and not upgraded:
            diff.append(f"{k.split('_')[0]}: {str(old.get(k))[:16]} -> {str(identity[k])[:16]}")
    if diff:
        raise UserError(
            f"--resume: {checkpoint} was trained with a different setup ({'; '.join(diff)}); "
            "resume with the same settings, or --overwrite to start afresh"
        )


def check_resume_config(checkpoint: str, config: ICRLConfig) -> None:
    """Refuse a checkpoint whose ``config.json`` disagrees with the model this run builds (an
    edited or copied config: its weights would be loaded into another architecture's reading)."""
    try:
        saved = read_json(Path(checkpoint) / "config.json")
    except (OSError, ValueError) as exc:
        raise UserError(f"--resume: {checkpoint}/config.json is unreadable ({exc})") from None
    diff = [
        f"{k}: {saved.get(k, _BEFORE_FIELD.get(k))!r} (checkpoint) vs {getattr(config, k)!r}"
        for k in _MODEL_FIELDS
        if saved.get(k, _BEFORE_FIELD.get(k)) != getattr(config, k)
    ]
    if diff:
        raise UserError(
            f"--resume: {checkpoint}/config.json does not describe this run's model "
            f"({'; '.join(diff[:4])}); resume with the same settings, or --overwrite"
        )


#: Written last into a checkpoint by ``Trainer._save_checkpoint`` (after the weights, our identity
#: file, the optimizer, scheduler and RNG states): a checkpoint whose state parses was saved whole.
TRAINER_STATE_FILE = "trainer_state.json"


def last_checkpoint(folder: str | Path) -> str | None:
    """The newest *complete* ``checkpoint-N`` in ``folder`` (None: none).

    ``transformers.trainer_utils.get_last_checkpoint`` returns the highest N whatever it holds; a
    save cut short (Ctrl-C, SIGTERM, a killed process) leaves a checkpoint without its trainer
    state (or with a truncated file), and resuming it fails on every rerun, or (no optimizer or
    state) silently restarts the schedule from step 0 on step-N weights.  Such a checkpoint is passed over (and
    named on stderr): the one saved before it is resumed, and the Trainer saves N again.
    """
    root = Path(folder)
    if not root.is_dir():
        return None
    numbered = []
    for path in root.glob(f"{PREFIX_CHECKPOINT_DIR}-*"):
        step = path.name.split("-", 1)[1]
        if path.is_dir() and step.isdigit():
            numbered.append((int(step), path))
    for _, path in sorted(numbered, reverse=True):
        try:
            read_json(path / TRAINER_STATE_FILE)
            return str(path)
        except (OSError, ValueError):
            pass
        print(f"lhf: note: {path} is incomplete (a save cut short): not resumed", file=sys.stderr)
    return None


def train(cfg: TrainConfig, model_config: ICRLConfig | None = None, progress: bool = True) -> Path:
    """Train, then write the final model, ``train_config.json``, the loss log and plot and the card.
    ``progress``: Trainer's progress bar."""
    cfg = resolve(cfg)  # a reporter not installed, a bad Trainer argument: said before anything
    if cfg.push_to_hub:
        require_token()  # the real Hub without a token: refused before any request, as `lhf push`
    out = Path(cfg.out)
    existed = out.is_dir() and any(out.iterdir())  # before the claim creates it
    with ExitStack() as claim:
        if int(os.environ.get("RANK", "0")) == 0:  # rank 0 holds the folder for every process
            claim.enter_context(
                output_folder(
                    out,
                    "model",
                    overwrite=cfg.overwrite,
                    resume=cfg.resume,
                    inputs=[cfg.dataset, cfg.selection],
                    legacy=MODEL_FILES,
                    resumable=True,
                    mutable=("README.md", MODEL_EVALS_FILE),  # evaluations update the card
                )
            )
        resume = None
        if cfg.resume:
            resume = last_checkpoint(out)
            if resume is None:
                fix = "--overwrite to train afresh" if existed else "train without --resume"
                raise NotFoundError(
                    f"--resume: no complete checkpoint-* folder in {out} to resume from: {fix}"
                )
        step = _train_into(cfg, model_config, out, resume, progress)
    # The final push, once the folder is whole and has its manifest: it is checked and pushed like
    # `lhf push` (manifest, card, no optimizer states), and the Hub copy verifies when loaded.
    if cfg.push_to_hub and int(os.environ.get("RANK", "0")) == 0:
        from .artifact import CheckpointArtifact  # deferred: artifact imports this module

        with library_bars(progress):  # as in _PushCheckpoints: Trainer turned the bars back on
            CheckpointArtifact.push(
                out,
                cfg.push_to_hub,
                private=cfg.hub_private,
                commit_message=f"lhf train: final model, step {step}",
            )
    return out


#: Files of a model folder written before output markers existed (``utils.outputs``).
MODEL_FILES = (TRAIN_CONFIG_FILE, "config.json", "checkpoint-*")


def _write_model(trainer, cfg: TrainConfig, out: Path, provenance, result, resume, wall) -> None:
    """Rank 0: the final weights, ``train_config.json``, the loss log and plot, and the card."""
    bad = [n for n, p in trainer.model.named_parameters() if not torch.isfinite(p).all()]
    if bad:  # e.g. a learning rate that made it diverge: not a model anyone should evaluate
        raise UserError(
            f"training diverged: {len(bad)} weight tensors hold NaN or infinite values (e.g. "
            f"{bad[0]}) at step {trainer.state.global_step} (lr {cfg.lr:g}): no model written; "
            "train again with a smaller --lr"
        )
    trainer.save_model(str(out), _internal_call=True)  # not pushed: the folder is not whole yet
    history = [r for r in trainer.state.log_history if "loss" in r]
    provenance.update(
        {
            "seed": cfg.seed,
            "versions": library_versions(["transformers", "accelerate", "safetensors"]),
            "resumed_from": resume,
            "global_step": trainer.state.global_step,
            "train_runtime_s": round(wall, 2),
            "final_loss": history[-1]["loss"] if history else None,
            "parameters": int(sum(p.numel() for p in trainer.model.parameters())),
            "metrics": result.metrics,
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
    )
    write_json_atomic(provenance, out / TRAIN_CONFIG_FILE)
    write_json_atomic(trainer.state.log_history, out / LOG_FILE)

    plot_loss(trainer.state.log_history, out / LOSS_PLOT)
    write_model_card(out, trainer.model.config, provenance)


def _train_into(
    cfg: TrainConfig, model_config, out: Path, resume: str | None, progress: bool = True
) -> int:
    trainer, provenance = build_trainer(cfg, model_config, progress)
    if resume is not None:
        check_resume(resume, trainer.lhf_identity)
        check_resume_config(resume, trainer.model.config)
        check_weights(Path(resume), trainer.model.config)  # a damaged checkpoint: one line
        step = read_json(Path(resume) / TRAINER_STATE_FILE).get("global_step")
        if isinstance(step, int) and step >= cfg.max_steps and (out / "config.json").is_file():
            # Trainer would take one more step and rewrite the finished model
            if trainer.is_world_process_zero():
                print(f"lhf: {out} is finished (step {step} of {cfg.max_steps}): nothing to "
                      "resume", file=sys.stderr)  # fmt: skip
            end_ranks()
            return step
        before = read_json(Path(resume) / IDENTITY_FILE).get("world_sizes") or [[0, None]]
        world = provenance["world_size"]
        sizes = before if before[-1][1] == world else [*before, [step, world]]
        trainer.lhf_identity["world_sizes"] = provenance["world_sizes"] = sizes
        if trainer.is_world_process_zero():  # what a rerun goes on from: said, not guessed
            print(f"lhf: resuming from {resume} (step {step} of {cfg.max_steps})", file=sys.stderr)
    if trainer.is_world_process_zero():
        d = provenance["dataset"]
        print(describe_coverage(d["env_id"], d["split_seed"], d["split_coverage"]), file=sys.stderr)
    t0 = time.perf_counter()
    result = trainer.train(resume_from_checkpoint=resume)
    wall = time.perf_counter() - t0
    try:
        if trainer.is_world_process_zero():
            _write_model(trainer, cfg, out, provenance, result, resume, wall)
    finally:  # after rank 0's writes; a failed one still releases the other ranks
        end_ranks()
    # ``train`` pushes the final folder, rank 0 alone and after the group is gone (an upload
    # longer than the group's timeout would otherwise fail rank 1 at the barrier).
    return trainer.state.global_step
