"""Type checks of config fields against their annotations.

The CLI converts flags by type, but a config built from Python or from a YAML spec gets whatever it
is given (YAML 1.1 reads ``1e-3`` as text, ``2.5`` histories is a float): ``check_types`` turns such
a value into one clear error naming the field, before anything runs.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, Literal

from lhf_hf.errors import UserError


def _ok(value: Any, hint: Any) -> bool:
    origin = typing.get_origin(hint)
    if hint is Any:
        return True
    if origin is Literal:
        return value in typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_ok(value, h) for h in typing.get_args(hint))
    if origin in (list, tuple):
        (item, *_) = typing.get_args(hint) or (Any,)
        return isinstance(value, list | tuple) and all(_ok(v, item) for v in value)
    if origin is dict:
        return isinstance(value, dict)
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:  # an int is a float's value too (lr: 1 is 1.0)
        return isinstance(value, int | float) and not isinstance(value, bool)
    if isinstance(hint, type):
        return isinstance(value, hint | dict)  # nested settings may still be a mapping here
    return True


def _name(hint: Any) -> str:
    origin = typing.get_origin(hint)
    if origin is Literal:
        return f"one of {typing.get_args(hint)!r}"
    if origin in (typing.Union, types.UnionType):  # None is "unset": not named
        return " or ".join(_name(h) for h in typing.get_args(hint) if h is not type(None))
    if origin in (list, tuple):
        (item, *_) = typing.get_args(hint) or (Any,)
        return f"a list of {_name(item)}"
    if hint is type(None):
        return "None"
    return {int: "an integer", float: "a number", str: "a string", bool: "true or false"}.get(
        hint, getattr(hint, "__name__", str(hint))
    )


def check_types(config: Any) -> None:
    """Raise ``UserError("<Class>.<field> must be <type>, got <value>")`` for the first field of
    dataclass ``config`` whose value does not match its annotation."""
    hints = typing.get_type_hints(type(config))
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if not _ok(value, hints[f.name]):
            note = ""
            if isinstance(value, str) and _ok(0.5, hints[f.name]):
                note = " (in YAML, write a number with a dot, e.g. 1.0e-3: 1e-3 reads as text)"
            raise UserError(
                f"{type(config).__name__}.{f.name} must be {_name(hints[f.name])}, "
                f"got {value!r}{note}"
            )


def config_from_record(cls, record: Any, where: str):
    """``cls(**record)`` for a config read back from an artifact's JSON (``where`` names the file
    and field): anything but an object of ``cls``'s fields is one ``UserError`` naming the file,
    not a ``TypeError`` from inside the constructor."""
    if not isinstance(record, dict):
        raise UserError(
            f"{where} is {type(record).__name__}, not an object of {cls.__name__} fields"
        )
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(record) - known)
    if unknown:
        raise UserError(
            f"{where} has fields {cls.__name__} does not know ({', '.join(unknown)}): the file is "
            "damaged or written by another lhf_hf version"
        )
    try:
        return cls(**record)
    except UserError as exc:
        raise UserError(f"{where}: {exc}") from None
