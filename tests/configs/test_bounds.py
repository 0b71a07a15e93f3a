"""Upper bounds of the counts a typo can blow up: ``--episodes`` (EvalConfig) and ``--max-steps``
(TrainConfig), checked when the config is made, with one line naming the field, its flag, the
bound and why; through the CLI that line is the command's whole error."""

from __future__ import annotations

import pytest

from lhf_hf.cli.main import main
from lhf_hf.configs import EvalConfig, TrainConfig
from lhf_hf.configs.evaluate import MAX_EPISODES
from lhf_hf.configs.train import MAX_STEPS
from lhf_hf.errors import UserError

EPISODES = (
    "EvalConfig.episodes (--episodes) must be between 1 and 10,000 (the paper evaluates 100; the "
    "context's positions and the returns kept grow with every episode), got {}"
)
MAX = (
    "TrainConfig.max_steps (--max-steps) must be at most 1,000,000 (20 times the reference's "
    "50,000; the trainer keeps a log entry per --logging-steps steps, in memory and in "
    "trainer_state.json), got {}"
)


def test_episodes_bound():
    assert MAX_EPISODES == 10_000
    assert EvalConfig(model="m", out="o", episodes=MAX_EPISODES).episodes == 10_000
    for bad in (0, -3, MAX_EPISODES + 1, 10**9):
        with pytest.raises(UserError) as err:
            EvalConfig(model="m", out="o", episodes=bad)
        assert str(err.value) == EPISODES.format(bad)


def test_max_steps_bound():
    assert MAX_STEPS == 1_000_000
    cfg = TrainConfig(dataset="d", objective="ad", out="o", max_steps=MAX_STEPS)
    assert cfg.max_steps == MAX_STEPS
    for bad in (MAX_STEPS + 1, 10**12):
        with pytest.raises(UserError) as err:
            TrainConfig(dataset="d", objective="ad", out="o", max_steps=bad)
        assert str(err.value) == MAX.format(bad)
    with pytest.raises(UserError, match=r"^TrainConfig.max_steps must be >= 1, got 0$"):
        TrainConfig(dataset="d", objective="ad", out="o", max_steps=0)


def test_the_cli_prints_the_bound_in_one_line(tmp_path, capsys):
    out = str(tmp_path / "o")
    assert main(["evaluate", "--model", "m", "--out", out, "--episodes", "20000"]) == 1
    assert capsys.readouterr().err == f"lhf evaluate: error: {EPISODES.format(20000)}\n"
    args = ["train", "--dataset", "d", "--objective", "ad", "--out", out, "--max-steps", "2000000"]
    assert main(args) == 1
    assert capsys.readouterr().err == f"lhf train: error: {MAX.format(2000000)}\n"
    assert not (tmp_path / "o").exists()  # refused before anything was made
