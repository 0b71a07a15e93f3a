"""Flags generated from config dataclasses: one field, one flag, one default, one help text."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
from dataclasses import dataclass
from typing import Literal

import pytest

from lhf_hf.cli import flags
from lhf_hf.cli.main import build_parser
from lhf_hf.configs import CollectConfig, EvalConfig, FilterConfig, TrainConfig, commands

CONFIGS = [CollectConfig, EvalConfig, FilterConfig, TrainConfig] + [
    obj
    for obj in vars(commands).values()
    if dataclasses.is_dataclass(obj) and obj.__module__ == commands.__name__
]


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_field_docs_reads_entries_and_continuations():
    doc = """Summary line: not a field.

    alpha: first line
        continues here.
    beta: one line.

    Notes: after a blank line, a new entry.
    """
    assert flags.field_docs(doc) == {
        "alpha": "first line continues here.",
        "beta": "one line.",
        "Notes": "after a blank line, a new entry.",
    }


@pytest.mark.parametrize("cls", CONFIGS, ids=lambda c: c.__name__)
def test_every_config_field_is_documented_once(cls):
    docs = flags.field_docs(inspect.getdoc(cls))
    names = [f.name for f in dataclasses.fields(cls)]
    assert [n for n in names if n not in docs] == []
    # entries for fields that no longer exist are stale text
    stale = [d for d in docs if d not in names and d[0].islower()]
    assert stale == []


def test_every_flag_is_one_config_field():
    """Each option of each command is a field of a config dataclass, with its choices and its
    docstring text, and its default is not in the parser (the dataclass keeps the only one)."""
    fields = {}
    for cls in CONFIGS:
        docs = flags.field_docs(inspect.getdoc(cls))
        for f in dataclasses.fields(cls):
            fields.setdefault(f.name, []).append((cls, docs[f.name]))
    checked = 0
    for name, sub in _subparsers(build_parser()).items():
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.dest in fields, f"lhf {name} {action.option_strings}: no config field"
            helps = [
                flags._help(p)
                for cls, _ in fields[action.dest]
                for p in flags.params(cls, only=(action.dest,))
            ]
            assert action.help in helps, f"lhf {name} {action.dest}: help not from the docstring"
            if action.option_strings:
                assert action.default is argparse.SUPPRESS, f"lhf {name} {action.dest}"
            checked += 1
    assert checked > 60


def test_unset_flags_leave_the_dataclass_defaults():
    parser = build_parser()
    args = parser.parse_args(["collect", "darkroom", "--out", "x"])
    assert flags.values(args, args.config) == {"env_id": "darkroom"}
    assert CollectConfig(**flags.values(args, args.config)) == CollectConfig(env_id="darkroom")
    args = parser.parse_args(
        ["train", "--dataset", "d", "--objective", "dpt", "--out", "o", "--lr", "0.5", "--resume"]
    )
    cfg = TrainConfig(**flags.values(args, args.fields))
    assert (cfg.lr, cfg.resume, cfg.batch_size) == (0.5, True, TrainConfig.batch_size)
    args = parser.parse_args(["evaluate", "--model", "m", "--out", "o", "--env", "darkroom"])
    assert EvalConfig(**flags.values(args, args.fields)).env_id == "darkroom"
    args = parser.parse_args(["collect", "darkroom", "--out", "x", "--no-progress"])
    assert flags.values(args, args.output) == {"out": "x", "progress": False}


def test_choices_types_and_required_come_from_the_field():
    parser = build_parser()
    with pytest.raises(SystemExit):
        parser.parse_args(["filter", "d", "--out", "o", "--strategy", "greedy"])
    with pytest.raises(SystemExit):  # an int field refuses a float
        parser.parse_args(["collect", "darkroom", "--out", "x", "--histories", "2.5"])
    with pytest.raises(SystemExit):  # a field without default is required
        parser.parse_args(["train", "--dataset", "d", "--out", "o"])
    with pytest.raises(SystemExit):  # resume and overwrite exclude each other
        parser.parse_args(["derive", "half", "s", "--out", "o", "--resume", "--overwrite"])
    args = parser.parse_args(["compare", "--baseline", "a", "b", "--lhf", "c"])
    assert commands.CompareOptions(**flags.values(args, args.fields)).baseline == ["a", "b"]


def test_a_field_without_a_doc_or_a_command_line_form_is_refused():
    @dataclass
    class Undocumented:
        """No entries."""

        x: int = 1

    @dataclass
    class Nested:
        """Nested.

        inner: a dataclass has no flag form.
        """

        inner: CollectConfig | None = None

    with pytest.raises(TypeError, match="Undocumented.x has no 'name: text' entry"):
        flags.params(Undocumented)
    with pytest.raises(TypeError, match="no command-line form"):
        flags.params(Nested)
    assert flags.params(Nested, skip=("inner",)) == []


def test_literal_fields_give_choices():
    @dataclass
    class Choice:
        """Choice.

        mode: one of two.
        """

        mode: Literal["a", "b"] = "a"

    (p,) = flags.params(Choice)
    assert (p.kind, p.choices, p.default) == (str, ("a", "b"), "a")


def _defaults(fn) -> dict:
    return {
        n: p.default
        for n, p in inspect.signature(fn).parameters.items()
        if p.default is not inspect.Parameter.empty
    }


def test_functions_behind_the_commands_have_the_same_defaults():
    """Where a command's options are also keywords of the function it calls, the two defaults are
    the same (the flag's help shows the dataclass's)."""
    from lhf_hf.cli.envs import collect as env_rows
    from lhf_hf.collection import collect
    from lhf_hf.evaluation import compare
    from lhf_hf.filtering.run import run_filter
    from lhf_hf.histories.derive import derive_half
    from lhf_hf.hub import push
    from lhf_hf.reproduce import reproduce

    def same(cls, fn, rename=None):
        rename = rename or {}
        fn_defaults = _defaults(fn)
        shared = 0
        for f in dataclasses.fields(cls):
            key = rename.get(f.name, f.name)
            if key in fn_defaults and f.default is not dataclasses.MISSING:
                assert fn_defaults[key] == f.default, f"{fn.__name__}({key}) vs {cls.__name__}"
                shared += 1
        return shared

    output = commands.OutputOptions
    assert same(output, collect) == 3
    assert same(output, derive_half) == 3
    assert same(commands.DeriveOptions, derive_half) == 1
    assert same(output, run_filter) == 2
    assert same(commands.FilterInputs, run_filter) == 1
    assert same(commands.PushOptions, push, {"message": "commit_message"}) == 5
    assert (
        same(commands.ReproduceOptions, reproduce, {"experiment": "name"}) == 6
    )  # + jobs, objectives
    assert same(commands.EnvsOptions, env_rows) == 3
    assert same(commands.CompareOptions, compare) == 2
