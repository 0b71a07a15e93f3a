"""Command-line arguments generated from config dataclasses and function signatures.

Every flag of ``lhf`` comes from one field: a dataclass field (``CollectConfig``, ``TrainConfig``,
...) or a parameter of the function a command calls (``collect``'s ``out``, ``push``'s
``repo_id``).  Its type, choices (``Literal``), default and help text (the field's entry in the
docstring, ``name: text`` lines) are read from there, so a field is written once and a flag cannot
drift from it.  Flags left unset are absent from the namespace (``argparse.SUPPRESS``): the
dataclass or the function applies its own default, the only one there is.

Like transformers' ``HfArgumentParser``, but for functions as well as dataclasses, with help taken
from docstrings, and without the defaults being copied into the parser.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
import types
import typing
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Literal

from lhf_hf.configs.commands import OutputOptions

REQUIRED = object()  # a field without a default


@dataclass(frozen=True)
class Param:
    """One field as a command-line argument.

    name: the field's name (the namespace attribute, and the keyword it is passed back as).
    kind: ``str``, ``int``, ``float``, ``bool``, ``list`` (one or more strings) or ``dict``
        (``KEY=VALUE``, the flag repeated once per key; the values stay text for the field's
        owner to read).
    default: the field's default, or ``REQUIRED``.
    choices: the allowed values (a ``Literal`` type), or None.
    help: the field's docstring entry.
    """

    name: str
    kind: type
    default: Any
    choices: tuple | None
    help: str


def field_docs(doc: str | None) -> dict[str, str]:
    """``name: text`` entries of a docstring (continuation lines indented deeper), one per field."""
    docs: dict[str, str] = {}
    current, indent = None, 0
    for line in (doc or "").splitlines():
        m = re.match(r"^(\s*)([A-Za-z_]\w*): (.+)$", line)
        if m and (current is None or len(m.group(1)) <= indent):
            current, indent = m.group(2), len(m.group(1))
            docs[current] = m.group(3).strip()
        elif current and line.strip() and len(line) - len(line.lstrip()) > indent:
            docs[current] += " " + line.strip()
        else:
            current = None
    return docs


def _kind(hint: Any, where: str) -> tuple[type, tuple | None]:
    """(kind, choices) of a type hint; ``X | None`` is X; a union with ``str`` is ``str``."""
    origin = typing.get_origin(hint)
    if origin is Literal:
        choices = typing.get_args(hint)
        return type(choices[0]), choices
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) == 1:
            return _kind(args[0], where)
        if str in args:  # e.g. tasks: "all" or a list of indices; a path: str | Path
            return str, None
    if origin is list and typing.get_args(hint) in ((str,), ()):
        return list, None
    if (origin or hint) is dict and typing.get_args(hint)[:1] in ((str,), ()):
        return dict, None
    if hint in (str, int, float, bool):
        return hint, None
    raise TypeError(f"{where}: no command-line form for type {hint!r}; skip the field")


def params(
    obj: type | Callable, skip: Iterable[str] = (), only: Iterable[str] | None = None
) -> list[Param]:
    """The fields of dataclass ``obj`` or the parameters of function ``obj`` (those in ``only``
    when given), minus ``skip``."""
    skip = set(skip)
    if only is not None:
        only = set(only)
        missing = (
            only - {f.name for f in dataclasses.fields(obj)}
            if dataclasses.is_dataclass(obj)
            else set()
        )
        if missing:
            raise TypeError(f"{obj.__qualname__} has no fields {sorted(missing)}")
    hints = typing.get_type_hints(obj)
    docs = field_docs(inspect.getdoc(obj))
    if dataclasses.is_dataclass(obj):
        entries = []
        for f in dataclasses.fields(obj):
            if f.default is not dataclasses.MISSING:
                default = f.default
            elif f.default_factory is not dataclasses.MISSING:
                default = f.default_factory()
            else:
                default = REQUIRED
            entries.append((f.name, default))
    else:
        entries = [
            (p.name, REQUIRED if p.default is inspect.Parameter.empty else p.default)
            for p in inspect.signature(obj).parameters.values()
        ]
    out = []
    for name, default in entries:
        if name in skip or (only is not None and name not in only):
            continue
        where = f"{obj.__qualname__}.{name}"
        if name not in docs:
            raise TypeError(f"{where} has no 'name: text' entry in the docstring")
        kind, choices = _kind(hints[name], where)
        out.append(Param(name, kind, default, choices, docs[name]))
    return out


def _help(p: Param) -> str:
    # docstrings are reStructuredText: ``x`` reads as `x` on a terminal
    text = p.help.replace("``", "`").replace("%", "%%").replace("None = ", "unset: ")
    if p.kind is bool and p.default is True:  # the --no-NAME switch
        text = "do not " + text[0].lower() + text[1:]
    shown = p.default not in (REQUIRED, None, {}) and p.kind is not bool
    if shown and "default" not in text:  # a text that speaks of its default says it better
        text = f"{text.rstrip('.')} (default: {p.default})"
    return text


def add_params(
    parser: argparse.ArgumentParser,
    obj: type | Callable,
    *,
    positional: Iterable[str] = (),
    skip: Iterable[str] = (),
    only: Iterable[str] | None = None,
    flags: dict[str, str] | None = None,
    group: argparse._ActionsContainer | None = None,
) -> list[str]:
    """Add one argument per field of ``obj`` (dataclass or function) to ``parser``.

    positional: fields given as positional arguments (the rest are ``--flags``).
    skip: fields the command sets itself (not on the command line).
    only: add these fields alone (e.g. the part of a dataclass that goes into a group).
    flags: a flag other than ``--field-name`` for a field (e.g. ``env_id`` -> ``--env``).
    group: where to add the arguments (e.g. a mutually exclusive group); default ``parser``.
    Returns the names added.
    """
    positional, flags = set(positional), flags or {}
    target = group or parser
    names = []
    for p in params(obj, skip, only):
        names.append(p.name)
        kw: dict[str, Any] = {"help": _help(p)}
        if p.name in positional:
            if p.kind is list:
                kw["nargs"] = "+"
            elif p.kind is not bool:
                kw["type"] = p.kind
            if p.choices:
                kw["choices"] = p.choices
            parser.add_argument(p.name, **kw)
            continue
        flag = flags.get(p.name, "--" + p.name.replace("_", "-"))
        kw.update(dest=p.name, default=argparse.SUPPRESS)
        if p.kind is dict:
            kw.update(action=_KeyValue, metavar="KEY=VALUE")
        elif p.kind is bool:
            if p.default is True:  # a default-on switch is turned off with --no-NAME
                flag = flags.get(p.name, "--no-" + p.name.replace("_", "-"))
                kw["action"] = "store_false"
            else:
                kw["action"] = "store_true"
        else:
            kw["type"] = str if p.kind is list else p.kind
            if p.kind is list:
                kw["nargs"] = "+"
            if p.choices:
                kw["choices"] = p.choices
            kw["metavar"] = None if p.choices else flag.lstrip("-").replace("-", "_").upper()
            if p.default is REQUIRED:
                kw["required"] = True
        target.add_argument(flag, **kw)
    return names


class _KeyValue(argparse.Action):
    """``--flag KEY=VALUE``, repeatable: one dict of every key given (a key given twice: the
    last value)."""

    def __call__(self, parser, namespace, text, option_string=None):
        key, sep, value = text.partition("=")
        if not sep or not key.strip():
            raise argparse.ArgumentError(self, f"expected KEY=VALUE, got {text!r}")
        given = dict(getattr(namespace, self.dest, None) or {})
        given[key.strip()] = value
        setattr(namespace, self.dest, given)


def values(args: argparse.Namespace, names: Iterable[str]) -> dict[str, Any]:
    """The fields of ``names`` given on the command line (unset ones are absent: their defaults
    are the dataclass's or function's own)."""
    return {n: getattr(args, n) for n in names if hasattr(args, n)}


def add_progress(parser: argparse.ArgumentParser) -> list[str]:
    """``--no-progress`` for a long command: the one definition, ``OutputOptions.progress``
    (commands that take ``OutputOptions`` whole get it with the rest)."""
    return add_params(parser, OutputOptions, only=("progress",))


def progress(args: argparse.Namespace) -> bool:
    """Whether the command line asked for progress bars (``--no-progress``: False)."""
    return getattr(args, "progress", True)
