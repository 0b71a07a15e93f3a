"""Runs under ``accelerate launch``: the shipped config is found from the package, and a launch
that asked for more processes than it started says so."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from lhf_hf.cli.main import main
from lhf_hf.utils import launcher
from lhf_hf.utils.launcher import accelerate_config, launch_mismatch

#: what accelerate's simple launcher sets for `--cpu --num_processes 2` (no WORLD_SIZE)
SIMPLE = {"ACCELERATE_USE_CPU": "True", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": "29500"}


def test_the_shipped_config_is_package_data_for_two_cpu_processes(capsys):
    path = accelerate_config()
    assert path.parent.parent == Path(launcher.__file__).resolve().parents[1]  # inside lhf_hf
    cfg = yaml.safe_load(path.read_text())
    assert (cfg["distributed_type"], cfg["use_cpu"], cfg["num_processes"]) == ("MULTI_GPU", True, 2)
    assert main(["accelerate-config"]) == 0
    assert capsys.readouterr().out.strip() == str(path)


@pytest.mark.parametrize(
    "env, parent, said",
    [
        (SIMPLE, ["accelerate", "launch", "--cpu", "--num_processes", "2", "-m", "lhf_hf"], "2 "),
        (SIMPLE, ["accelerate", "launch", "--num-processes=3", "x.py"], "3 "),
        (SIMPLE, ["accelerate", "launch", "--config_file", "multi_cpu.yaml"], "more than one "),
        (SIMPLE, [], "more than one "),  # no /proc: the count is unknown, the mismatch is not
        (SIMPLE, ["accelerate", "launch", "--num_processes", "1", "x.py"], None),  # a user's port
        ({**SIMPLE, "WORLD_SIZE": "2"}, [], None),  # torchrun started them (the shipped config)
        ({**SIMPLE, "PMI_SIZE": "2"}, [], None),  # mpirun did
        ({"ACCELERATE_USE_CPU": "True"}, [], None),  # one process asked for
        ({"MASTER_PORT": "29500"}, [], None),  # not accelerate's launcher
    ],
)
def test_a_launch_that_started_fewer_processes_is_named(monkeypatch, env, parent, said):
    monkeypatch.setattr(launcher, "_parent_command_line", lambda: parent)
    found = launch_mismatch(env)
    assert (found is None) if said is None else (f"asked for {said}processes" in found), found


def test_every_command_says_it_first(monkeypatch, capsys):
    monkeypatch.setattr(launcher, "_parent_command_line", lambda: ["--num_processes", "2"])
    for k, v in SIMPLE.items():
        monkeypatch.setenv(k, v)
    monkeypatch.delenv("WORLD_SIZE", raising=False)
    assert main(["accelerate-config"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("lhf accelerate-config: warning: accelerate launch was asked for 2 "
                          "processes but started this one alone"), err  # fmt: skip
    assert 'accelerate launch --config_file "$(lhf accelerate-config)"' in err


@pytest.mark.slow
def test_accelerate_launch_cpu_with_two_processes_warns(tmp_path):
    """The real launcher: `accelerate launch --cpu --num_processes 2` starts one process, which
    says so; the shipped config is found by the installed package."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    env.pop("WORLD_SIZE", None)
    r = subprocess.run(
        [sys.executable, "-m", "accelerate.commands.launch", "--cpu", "--num_processes", "2",
         "--main_process_port", "29561", "-m", "lhf_hf", "accelerate-config"],
        capture_output=True, text=True, timeout=120, cwd=tmp_path, env=env,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == str(accelerate_config())  # one process printed it
    assert r.stderr.count("warning: accelerate launch was asked for 2 processes") == 1, r.stderr
