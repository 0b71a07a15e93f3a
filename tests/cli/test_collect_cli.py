"""``lhf collect`` / ``lhf derive`` from the command line: outputs and clear errors."""

import json

import pytest
import torch

from lhf_hf.cli.main import main


@pytest.mark.slow
def test_collect_and_derive(tmp_path, capsys):
    out = tmp_path / "d"
    args = [
        "collect",
        "darkroom",
        "--out",
        str(out),
        "--tasks",
        "40",
        "--histories",
        "2",
        "--steps",
        "40",
        "--workers",
        "1",
        "--no-progress",
    ]
    assert main(args) == 0
    assert "tasks=1, histories=2, frames=80" in capsys.readouterr().out
    assert main(args) == 1
    assert "--resume" in capsys.readouterr().err
    assert main(["derive", "half", str(out), "--out", str(tmp_path / "h")]) == 0
    assert "frames=40" in capsys.readouterr().out


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--algo", "sac"], "needs continuous actions"),
        (["--steps", "30"], "multiple of the horizon"),
        (["--tasks", "99"], "out of range"),
        (["--histories", "0"], "histories must be >= 1"),
    ],
)
def test_bad_input_fails_before_work(tmp_path, capsys, extra, message):
    out = tmp_path / "never"
    assert main(["collect", "darkroom", "--out", str(out), *extra]) == 1
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_unknown_env_and_protocol(tmp_path, capsys):
    assert main(["collect", "darkroom-xl", "--out", str(tmp_path / "x")]) == 1
    assert "valid ids" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["collect", "darkroom", "--out", str(tmp_path / "x"), "--protocol", "greedy"])


def test_derive_missing_source(tmp_path, capsys):
    assert main(["derive", "half", str(tmp_path / "none"), "--out", str(tmp_path / "h")]) == 1
    assert "no dataset" in capsys.readouterr().err


def test_batched_options_reach_the_dataset(tmp_path, capsys):
    out = tmp_path / "b"
    base = ["collect", "darkroom", "--collector", "batched", "--tasks", "3,40,62"]
    base += ["--histories", "2", "--steps", "40", "--no-progress"]
    assert main([*base, "--out", str(out), "--tasks-per-chunk", "2"]) == 0
    info = json.loads((out / "meta" / "lhf_info.json").read_text())
    assert '"tasks_per_chunk": 2' in json.dumps(info)  # the flag is not dropped on the way
    if not torch.cuda.is_available():  # a clear error before any work
        assert main([*base, "--out", str(tmp_path / "g"), "--device", "cuda"]) == 1
        assert "torch sees no CUDA device" in capsys.readouterr().err
        assert not (tmp_path / "g").exists()


@pytest.mark.slow
def test_killed_collection_leaves_no_worker_running(tmp_path):
    """kill -9 of `lhf collect --workers 2`: its SB3 worker processes exit too (no orphans that
    finish the queued tasks into the folder)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    import psutil

    out = tmp_path / "d"
    cmd = [sys.executable, "-m", "lhf_hf", "collect", "darkroom", "--out", str(out), "--workers",
           "2", "--collector", "sb3", "--tasks", "3,10,40,62", "--histories", "10", "--steps", "4000", "--no-progress"]  # fmt: skip
    parent = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers = []
    deadline = time.monotonic() + 120
    while len(workers) < 2 and time.monotonic() < deadline:
        time.sleep(0.5)
        workers = [
            c
            for c in psutil.Process(parent.pid).children()
            if "spawn_main" in " ".join(c.cmdline())
        ]
    assert len(workers) == 2, "the workers did not start"
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait(timeout=30)
    gone, alive = psutil.wait_procs(workers, timeout=30)
    assert not alive, [p.pid for p in alive]
    assert not (out / "meta" / "info.json").exists()  # nothing finished it behind our back


@pytest.mark.parametrize(
    "argv, collector, said",
    [
        (["darkroom"], "batched", "the batched collector (the default for PPO on darkroom; "
                                  "--collector sb3 runs the SB3 reference)"),
        (["darkroom", "--collector", "sb3"], "sb3", None),
        (["metaworld-reach"], "sb3", "the sb3 collector (the default for PPO on metaworld-reach)"),
        (["metaworld-reach", "--algo", "sac"], "sb3", "the default for SAC on metaworld-reach"),
    ],
)  # fmt: skip
def test_the_default_collector_is_said_and_passed_resolved(
    tmp_path, capsys, monkeypatch, argv, collector, said
):
    import lhf_hf.collection

    ran = []
    monkeypatch.setattr(lhf_hf.collection, "collect", lambda config, *a, **k: ran.append(config))
    assert main(["collect", *argv, "--tasks", "0", "--out", str(tmp_path / "d")]) == 0
    assert [c.collector for c in ran] == [collector]
    err = capsys.readouterr().err
    assert (said in err) if said else ("collector" not in err), err


def test_a_resume_goes_on_with_the_collector_the_folder_was_started_with(
    tmp_path, capsys, monkeypatch
):
    """A collection started with SB3 (e.g. before the batched default): ``--resume`` without
    ``--collector`` continues it with SB3 (a batched config would be refused as another one)."""
    import lhf_hf.collection

    out = tmp_path / "d"
    (out / "meta").mkdir(parents=True)
    (out / "meta" / "lhf_config.json").write_text(json.dumps({"collector": "sb3"}))
    ran = []
    monkeypatch.setattr(lhf_hf.collection, "collect", lambda config, *a, **k: ran.append(config))
    argv = ["collect", "darkroom", "--tasks", "0", "--out", str(out)]
    assert main([*argv, "--resume"]) == 0 and ran.pop().collector == "sb3"
    assert f"the sb3 collector (the one {out} was started with)" in capsys.readouterr().err
    assert main([*argv, "--resume", "--collector", "batched"]) == 0  # as asked: refused later
    assert ran.pop().collector == "batched"
    assert main([*argv, "--overwrite"]) == 0 and ran.pop().collector == "batched"


def test_an_interrupted_collection_says_what_resume_keeps(tmp_path):
    """Tasks are written a chunk at a time: an interrupt says how many finished tasks --resume
    keeps, or that none had finished and why."""
    from lhf_hf.cli.collect import kept_tasks
    from lhf_hf.configs import CollectConfig
    from lhf_hf.histories.writer import write_task
    from tests.histories.test_writer import fake_task

    # 3 tasks of 3 histories x 40 transitions (fake_task's shape), Darkroom's horizon 20
    sb3 = CollectConfig("darkroom", tasks="0,1,2", histories=3, steps=40, collector="sb3")
    batched = CollectConfig("darkroom", tasks="0,1,2", histories=3, steps=40, collector="batched")
    assert kept_tasks(sb3, tmp_path) == "no task had finished, so --resume starts over"
    assert kept_tasks(batched, tmp_path) == (
        "no task had finished, so --resume starts over (the batched collector writes 3 tasks at a "
        "time: --tasks-per-chunk sets how many)"
    )
    write_task(tmp_path, 0, fake_task(task=0), horizon=20)
    assert kept_tasks(sb3, tmp_path) == "1 of 3 tasks are kept: --resume continues from them"
