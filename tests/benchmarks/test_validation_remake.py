"""benchmarks/validation/remake.sh: every command it runs is one its tool accepts, and it measures on
the validation goals only (a flag typo would otherwise surface hours into a re-make)."""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import shlex
import shutil
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


def _dry_run(*parts: str, root: Path) -> list[list[str]]:
    """The commands the script prints, run from a copy under ``root``: a checkout's own data/ and
    finished results/validation parts would make it skip their commands."""
    here = root / "benchmarks" / "validation"
    here.mkdir(parents=True)
    for name in ("remake.sh", "goals.py"):
        shutil.copy2(SCRIPT.parent / name, here / name)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    done = subprocess.run(["bash", str(here / "remake.sh"), "--dry-run", *parts],
                          capture_output=True, text=True, env=env, check=False)  # fmt: skip
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


def test_every_command_parses_and_measures_on_validation_goals(monkeypatch, tmp_path):
    from lhf_hf.envs import split_part
    from lhf_hf.reproduce.experiment import load_experiment

    commands = _dry_run(root=tmp_path)
    envs = [c for c in commands if c[0] == "env"]
    assert envs and all("ATEN_CPU_CAPABILITY=avx2" in c for c in envs)  # the AVX2 main job
    commands = [[w for w in c if "=" not in w][1:] if c[0] == "env" else c for c in commands]
    tools = [c[0] if c[0] == "lhf" else c[1] for c in commands if c[0] in ("lhf", "python")]
    assert {"lhf", "benchmarks/bench_icrl_curve.py", "benchmarks/compare_curves.py",
            "benchmarks/eval_noise.py", "benchmarks/dicp_convergence.py",
            "benchmarks/validation/goals.py", "benchmarks/validation/main_job_runs.py"} <= set(tools)  # fmt: skip
    parser = build_parser()
    kinds = set()
    for command in commands:
        if command[0] == "lhf":
            args = parser.parse_args(command[1:])
            kinds.add(command[1])
            if command[1] == "reproduce":  # the validation spec, both presets, on validation
                exp = load_experiment(args.experiment, args.preset)
                assert exp.evaluate["tasks"] == "validation" and exp.collect["tasks"] == "fit"
                continue
            kind = CONFIGS[command[1]]  # the CLI's flags are the config's fields
            config = kind(**values(args, [f.name for f in dataclasses.fields(kind)]))
            if command[1] == "collect":
                assert config.tasks == sorted(split_part("darkroom", "fit", 0))
            if command[1] == "evaluate":
                assert config.tasks == "validation" and config.rollouts == 4
        elif command[0] == "python":
            args = _parses(command[1:], monkeypatch)
            if command[1].endswith("bench_icrl_curve.py"):
                assert args.tasks == "validation" and not args.report_on_test
        else:
            assert command[0] in ("rm", "mkdir", "cp"), command
            assert all(a.startswith(("-", "runs/", "results/validation/")) for a in command[1:])
    assert kinds == {"collect", "train", "evaluate", "reproduce"}


def test_an_unknown_part_is_refused():
    done = subprocess.run(["bash", str(SCRIPT), "--dry-run", "bogus"], capture_output=True,
                          text=True, check=False)  # fmt: skip
    assert done.returncode == 2 and "unknown part 'bogus'" in done.stderr


def _goals_module():
    path = ROOT / "benchmarks" / "validation" / "goals.py"
    spec = importlib.util.spec_from_file_location("validation_goals", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_record_counts_only_when_every_goal_list_it_holds_is_today_s(tmp_path):
    goals = _goals_module()
    today = [2, 35, 42, 44, 54, 55, 77, 80]  # Darkroom split 0 (tests/envs/test_registry.py)
    earlier = [12, 68, 36, 17, 64, 27, 45, 61]  # split 0's before the disjoint draw
    f = tmp_path / "eval_results.json"
    # lhf evaluate's result: the config's "validation" string is not a goal list
    f.write_text(json.dumps({"config": {"tasks": "validation"}, "tasks": today[::-1]}))
    assert goals.current(f, [0])
    f.write_text(json.dumps({"config": {"tasks": "validation"}, "tasks": earlier}))
    assert not goals.current(f, [0])
    c = tmp_path / "curve.json"  # bench_icrl_curve.py: one list per objective
    c.write_text(json.dumps({"objectives": {"ad": {"tasks": today}, "dicp": {"tasks": earlier}}}))
    assert not goals.current(c, [0])
    c.write_text(json.dumps({"objectives": {"ad": {"tasks": today}}}))
    assert goals.current(c, [0])
    for bad in ("", "[1, 2]", "{}", '{"tasks": "validation"}'):
        f.write_text(bad)
        assert not goals.current(f, [0])  # unreadable or no goals: not done
    assert not goals.current(tmp_path / "missing.json", [0])


def test_a_part_is_done_once_its_goals_file_names_today_s_goals_of_each_split(tmp_path):
    goals = _goals_module()
    part = tmp_path / "main-job"
    assert not goals.current(part, [0, 1, 2])
    script = ROOT / "benchmarks" / "validation" / "goals.py"
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}

    def cli(*args):
        return subprocess.run([sys.executable, str(script), *args], env=env, check=False)

    assert cli("write", str(part), "--splits", "0", "1", "2").returncode == 0
    assert goals.current(part, [0, 1, 2]) and not goals.current(part, [0])
    written = json.loads((part / "goals.json").read_text())
    assert written["0"] == [2, 35, 42, 44, 54, 55, 77, 80] and set(written) == {"0", "1", "2"}
    assert cli("check", str(part), "--splits", "0", "1", "2").returncode == 0
    assert cli("check", str(part)).returncode == 1
    written["1"] = written["1"][:-1]  # one split's goals not today's
    (part / "goals.json").write_text(json.dumps(written))
    assert not goals.current(part, [0, 1, 2])
