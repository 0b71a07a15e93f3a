"""benchmarks/validation/remake.sh: every command it runs is one its tool accepts, and it measures on
the validation goals only (a flag typo would otherwise surface hours into a re-make)."""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from lhf_hf.cli.flags import values
from lhf_hf.cli.main import build_parser
from lhf_hf.configs import CollectConfig, EvalConfig, TrainConfig

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "validation" / "remake.sh"
CONFIGS = {"collect": CollectConfig, "train": TrainConfig, "evaluate": EvalConfig}
PARSE_ARGS = argparse.ArgumentParser.parse_args  # before any test patches it


def _dry_run(*parts: str) -> list[list[str]]:
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    done = subprocess.run(["bash", str(SCRIPT), "--dry-run", *parts], capture_output=True,
                          text=True, env=env, check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr
    return [shlex.split(line[2:]) for line in done.stdout.splitlines() if line.startswith("+ ")]


def _parses(argv: list[str], monkeypatch) -> argparse.Namespace:
    """The benchmark script's own parser on ``argv`` (its main() stops once it has parsed)."""
    path = ROOT / argv[0]
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    parsed = {}

    def stop(self, args=None, namespace=None):
        parsed["args"] = PARSE_ARGS(self, args, namespace)
        raise SystemExit(0)

    with monkeypatch.context() as patch, pytest.raises(SystemExit) as info:
        patch.setattr(argparse.ArgumentParser, "parse_args", stop)
        patch.setattr(sys, "argv", argv)
        module.main()
    assert info.value.code == 0 and "args" in parsed, argv
    return parsed["args"]


def test_every_command_parses_and_measures_on_validation_goals(monkeypatch):
    commands = _dry_run()
    tools = [c[0] if c[0] == "lhf" else c[1] for c in commands if c[0] in ("lhf", "python")]
    assert {"lhf", "benchmarks/bench_icrl_curve.py", "benchmarks/compare_curves.py",
            "benchmarks/eval_noise.py", "benchmarks/dicp_convergence.py"} <= set(tools)  # fmt: skip
    parser = build_parser()
    for command in commands:
        if command[0] == "lhf":
            args = parser.parse_args(command[1:])
            kind = CONFIGS[command[1]]  # the CLI's flags are the config's fields
            config = kind(**values(args, [f.name for f in dataclasses.fields(kind)]))
            if command[1] == "collect":
                assert config.tasks == sorted(
                    __import__("lhf_hf.envs", fromlist=["x"]).split_part("darkroom", "fit", 0)
                )
            if command[1] == "evaluate":
                assert config.tasks == "validation" and config.rollouts == 4
        elif command[0] == "python":
            args = _parses(command[1:], monkeypatch)
            if command[1].endswith("bench_icrl_curve.py"):
                assert args.tasks == "validation" and not args.report_on_test
        else:
            assert command[0] in ("rm", "mkdir", "cp"), command


def test_an_unknown_part_is_refused():
    done = subprocess.run(["bash", str(SCRIPT), "--dry-run", "bogus"], capture_output=True,
                          text=True, check=False)  # fmt: skip
    assert done.returncode == 2 and "unknown part 'bogus'" in done.stderr
