"""The ``TrainingArguments`` of an lhf training run (docs/training.md, "Trainer arguments").

lhf sets the arguments its flags own (``TrainConfig``: steps, batch, optimiser, logging, saving,
seed), reports where ``--report-to`` says, and passes any other ``TrainingArguments`` field given
as ``--training-arg KEY=VALUE`` (``TrainConfig.training_args``).  Everything is checked before
training starts: an unknown reporter or field (with the close matches named), a reporter that is
not installed, a value that is not of its field's type (read from ``TrainingArguments``' own
dataclass fields), and what ``TrainingArguments`` itself refuses.
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
import json
import types
import typing
from functools import cache
from pathlib import Path
from typing import Any, Literal

import torch
from transformers import TrainingArguments
from transformers.integrations import integration_utils

from lhf_hf.configs.train import TrainConfig, check_training_arg
from lhf_hf.errors import MissingExtraError, UnknownNameError, UserError

#: pip's name of an integration, where it is not the integration's own name
_PIP_NAMES = {"comet_ml": "comet-ml", "azure_ml": "azureml-core", "flyte": "flytekit"}


def _close(name: str, known) -> str:
    near = difflib.get_close_matches(name, list(known), n=3)
    return f" (did you mean {' or '.join(repr(n) for n in near)}?)" if near else ""


def installed_reporters() -> set[str]:
    """The reporting integrations installed here (what ``report_to="all"`` reports to)."""
    found = set(integration_utils.get_available_reporting_integrations())
    if integration_utils.is_flytekit_available():  # a known integration "all" leaves out
        found.add("flyte")
    return found


def check_reporters(cfg: TrainConfig) -> None:
    """Every name of ``cfg.report_to`` is an integration transformers knows, installed here."""
    known = sorted(integration_utils.INTEGRATION_TO_CALLBACK)
    for name in cfg.reporters:
        if name in ("none", "all"):
            continue
        if name not in known:
            raise UnknownNameError(
                f"--report-to {name!r} is not an integration transformers knows"
                f"{_close(name, known)}; one of none, all, {', '.join(known)}"
            )
        if name not in installed_reporters():
            raise MissingExtraError(
                f"--report-to {name}: the {name} integration is not installed here "
                f"(pip install {_PIP_NAMES.get(name, name)}), or report elsewhere"
            )


@cache
def training_arg_types() -> dict[str, Any]:
    """Every ``TrainingArguments`` field a caller may set, and its type."""
    hints = typing.get_type_hints(TrainingArguments)
    return {
        f.name: hints[f.name]
        for f in dataclasses.fields(TrainingArguments)
        if f.init and not f.name.startswith("_")
    }


def parse_training_args(given: dict[str, Any]) -> dict[str, Any]:
    """``TrainConfig.training_args`` checked against ``TrainingArguments``' fields, each text
    value read as its field's type (``"3"`` -> 3 for an int, ``"true"`` -> True for a bool)."""
    fields = training_arg_types()
    out = {}
    for key, value in given.items():
        check_training_arg(key)
        if key not in fields:
            raise UnknownNameError(
                f"TrainConfig.training_args: {key!r} is not a TrainingArguments field"
                f"{_close(key, fields)}"
            )
        out[key] = _value(key, value, fields[key])
    return out


def resolve(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` checked for training (reporters, other arguments), with its ``training_args`` read
    as their types: what the saved ``train_config.json`` records."""
    check_reporters(cfg)
    return dataclasses.replace(cfg, training_args=parse_training_args(cfg.training_args))


def training_arguments(cfg: TrainConfig, world: int, progress: bool) -> TrainingArguments:
    """The Trainer's arguments: lhf's own, then ``cfg.training_args`` (already ``resolve``d)."""
    own = dict(
        output_dir=str(Path(cfg.out).resolve()),  # recorded: absolute (a push hides it)
        max_steps=cfg.max_steps,
        per_device_train_batch_size=cfg.batch_size // world,
        learning_rate=cfg.lr,
        lr_scheduler_type="cosine",
        warmup_steps=cfg.warmup_steps,
        weight_decay=cfg.weight_decay,
        adam_beta1=cfg.beta1,
        adam_beta2=cfg.beta2,
        max_grad_norm=cfg.max_grad_norm,
        logging_steps=cfg.logging_steps,
        save_steps=cfg.save_steps,
        save_total_limit=None,  # trainer.RotateOwnCheckpoints keeps the newest 2, and foreign ones
        seed=cfg.seed,
        report_to=cfg.reporters,
        remove_unused_columns=False,
        dataloader_num_workers=0,
        dataloader_drop_last=True,  # with the sampler's whole batches, no step is short
        disable_tqdm=not progress,
        ddp_find_unused_parameters=False,
        use_cpu=not torch.cuda.is_available(),
        # Trainer creates the repo; trainer._PushCheckpoints pushes each saved checkpoint's weights
        # as it goes; `train` pushes the final folder with the lhf card at the end.
        push_to_hub=cfg.push_to_hub is not None,
        hub_model_id=cfg.push_to_hub,
        hub_strategy="end",
        hub_private_repo=cfg.hub_private if cfg.push_to_hub else None,
    )
    if not cfg.training_args:
        return TrainingArguments(**own)
    try:  # the defaults lhf chose (the scheduler, the loader's workers, ...) may be overridden
        args = TrainingArguments(**{**own, **cfg.training_args})
    except (ValueError, TypeError) as exc:
        raise refused(cfg, "TrainingArguments", exc) from None
    _check_accepted(cfg, args)
    return args


def _check_accepted(cfg: TrainConfig, args: TrainingArguments) -> None:
    """What ``TrainingArguments`` accepts but the run would refuse later, or ignore: said before
    anything is written, as what ``TrainingArguments`` refuses is."""
    if args.dataloader_num_workers < 0:  # torch's DataLoader refuses it at the first step
        raise refused(cfg, "lhf", ValueError("dataloader_num_workers must be 0 or more"))
    if (args.fp16 or args.fp16_full_eval) and not torch.cuda.is_available():
        # fp16 mixed precision is a CUDA feature: on a CPU the run would be float32 all along
        raise refused(
            cfg, "lhf", ValueError("fp16 needs a CUDA GPU; on a CPU use bf16=true or neither")
        )


def refused(cfg: TrainConfig, who: str, exc: Exception) -> UserError:
    """What TrainingArguments or Trainer said of a run with ``--training-arg``, as one line (e.g.
    ``eval_strategy="steps"``: lhf trains without an evaluation set)."""
    given = ", ".join(f"{k}={v!r}" for k, v in cfg.training_args.items())
    return UserError(f"TrainConfig.training_args ({given}): refused by {who}: {exc}")


# ---------------------------------------------------------------------------- values by type
_NOT = object()  # a text that does not read as a type
_TRUE, _FALSE = {"true", "yes", "1"}, {"false", "no", "0"}


def _members(hint: Any) -> list:
    """The alternatives of a type (``int | None`` -> [int, NoneType])."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return [m for a in typing.get_args(hint) for m in _members(a)]
    return [hint]


def _is(member: Any, kind: type) -> bool:
    return member is kind or typing.get_origin(member) is kind


def _enum_values(members: list) -> list[str] | None:
    for m in members:
        if isinstance(m, type) and issubclass(m, enum.Enum):
            return [e.value for e in m]
    return None


def _from_text(text: str, members: list) -> Any:
    """``text`` read as the first alternative it fits, the most specific first."""
    low = text.strip().lower()
    if type(None) in members and str not in members and low in ("none", "null"):
        return None
    if bool in members and low in _TRUE | _FALSE:
        return low in _TRUE
    for kind in (int, float):
        if kind in members:
            try:
                return kind(text)
            except ValueError:
                pass
    values = _enum_values(members)
    if values is not None:  # TrainingArguments turns the text into the enum member
        return text if text in values else _NOT
    if any(_is(m, dict) for m in members) and text.lstrip().startswith("{"):
        return _json(text)
    if any(_is(m, list) for m in members):
        if text.lstrip().startswith("["):
            return _json(text)
        if str not in members:
            return [t.strip() for t in text.split(",") if t.strip()]
    return text if str in members else _NOT


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError as exc:
        raise UserError(f"TrainConfig.training_args: {text!r} is not valid JSON ({exc})") from None


def _fits(value: Any, member: Any) -> bool:
    if member is type(None):
        return value is None
    if member is bool:
        return isinstance(value, bool)
    if member is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if member is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if typing.get_origin(member) is Literal:
        return value in typing.get_args(member)
    if _is(member, dict):
        return isinstance(value, dict)
    if _is(member, list):
        return isinstance(value, list)
    return False  # str is read by _from_text; other classes have no JSON form


def _json_like(value: Any) -> bool:
    if isinstance(value, dict):
        return all(isinstance(k, str) and _json_like(v) for k, v in value.items())
    if isinstance(value, list | tuple):
        return all(_json_like(v) for v in value)
    return value is None or isinstance(value, bool | int | float | str)


def _describe(members: list) -> str:
    names = {int: "an integer", float: "a number", bool: "true or false", str: "a text",
             type(None): "none"}  # fmt: skip
    values = _enum_values(members)
    if values is not None:
        return "one of " + ", ".join(values)
    out = [names.get(m) or ("a JSON mapping" if _is(m, dict) else "a list" if _is(m, list)
                            else getattr(m, "__name__", str(m))) for m in members]  # fmt: skip
    return " or ".join(dict.fromkeys(out))


def _value(key: str, value: Any, hint: Any) -> Any:
    members = _members(hint)
    where = f"TrainConfig.training_args[{key!r}]"
    if isinstance(value, str):
        parsed = _from_text(value, members)
        if parsed is _NOT:
            values = _enum_values(members) or []
            raise UserError(
                f"{where} must be {_describe(members)}, got {value!r}{_close(value, values)}"
            )
        return parsed
    if not _json_like(value):  # it is recorded in train_config.json
        raise UserError(f"{where} must be a number, text, true/false, a list or a mapping, "
                        f"got {value!r}")  # fmt: skip
    value = list(value) if isinstance(value, tuple) else value
    if any(_fits(value, m) for m in members):
        return value
    raise UserError(f"{where} must be {_describe(members)}, got {value!r}")
