"""``lhf envs`` through the installed console script and through ``main()``."""

import json
import shutil
import subprocess
import sys

import pytest

from lhf_hf.cli.main import main
from lhf_hf.envs import list_env_ids


@pytest.mark.slow
def test_console_script_json():
    exe = shutil.which("lhf") or f"{sys.executable} -m lhf_hf"
    out = subprocess.run(
        f"{exe} envs --json", shell=True, capture_output=True, text=True, check=True
    ).stdout
    rows = json.loads(out)
    assert [r["env_id"] for r in rows] == list_env_ids()
    dr = rows[0]
    assert (dr["horizon"], dr["num_tasks"], dr["num_train_tasks"], dr["num_test_tasks"]) == (
        20,
        81,
        73,
        8,
    )
    assert dr["optimal_return"]["max"] == 20 and dr["action_space"] == "Discrete(5)"


def test_table(capsys):
    assert main(["envs"]) == 0
    out = capsys.readouterr().out
    for env_id in list_env_ids():
        assert env_id in out
    assert "6233/328" in out and "13..20 (mean 16.54)" in out
    # the validation column: min(test, train // 4) held-out train tasks, by hand
    header, _, *lines = out.splitlines()
    assert header.split()[:6] == ["id", "horizon", "tasks", "train/test", "validation", "state"]
    rows = {line.split()[0]: line.split()[3:6] for line in lines}
    assert rows["darkroom"] == ["73/8", "8", "of"]  # min(8, 73 // 4 = 18)
    assert rows["dark-key-to-door"] == ["6233/328", "328", "of"]  # min(328, 1558)
    assert rows["metaworld-reach"] == ["50/50", "12", "of"]  # min(50, 50 // 4 = 12)


@pytest.mark.slow
def test_oracle_json(capsys):
    pytest.importorskip("metaworld")
    assert main(["envs", "--json", "--oracle", "--metaworld-tasks", "1"]) == 0
    rows = {r["env_id"]: r for r in json.loads(capsys.readouterr().out)}
    k2d = rows["dark-key-to-door"]["oracle"]
    assert k2d["tasks"] == 328 and k2d["tasks_at_optimum"] == 328 and k2d["mean_return"] == 2.0
    assert rows["darkroom"]["oracle"]["tasks_at_optimum"] == 8
    assert rows["metaworld-reach"]["oracle"]["success_rate"] == 1.0


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "envs" in capsys.readouterr().out
