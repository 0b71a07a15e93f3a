"""LeRobot's own reader on our datasets (issue 52): ``LeRobotDataset`` of lerobot 0.6.1, in its own
venv (``tests/hub/lerobot.lock``; Python 3.12, torch 2.11), from a local root and from a Hub repo
on the loopback test hub.  The dataset has sparse env task ids (3, 40, 62), the case that broke
LeRobot's reader in lhf's earlier layout."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from lhf_hf import constants as C
from tests.venvs import locked_venv

from .test_hub import CLI, _last_json, _ok

pytestmark = [pytest.mark.slow, pytest.mark.hub]

LOCK = Path(__file__).with_name("lerobot.lock")

#: Read with LeRobotDataset; print what the test compares against our own tables.
READ = """
import json, logging, sys
logging.basicConfig(level=logging.WARNING)
import lerobot
from lerobot.datasets.lerobot_dataset import LeRobotDataset

repo, root, picks = sys.argv[1], (sys.argv[2] or None), json.loads(sys.argv[3])
ds = LeRobotDataset(repo, root=root)
items = {}
for i in picks:
    item = ds[i]
    items[i] = {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in item.items()}
subset = LeRobotDataset(repo, root=root, episodes=[3, 4, ds.num_episodes - 1])
sub = [subset[j] for j in range(len(subset))]
window = LeRobotDataset(
    repo, root=root, delta_timestamps={"action": [-2.0, -1.0, 0.0], "next.reward": [0.0, 1.0]}
)
w = {i: window[i] for i in picks}
print(json.dumps({
    "version": lerobot.__version__,
    "len": len(ds),
    "episodes": ds.num_episodes,
    "tasks": ds.meta.total_tasks,
    "items": items,
    "subset_len": len(subset),
    "subset_episodes": sorted({int(x["episode_index"]) for x in sub}),
    "subset_tasks": sorted({x["task"] for x in sub}),
    "window": {i: {"action": v["action"].tolist(), "action_is_pad": v["action_is_pad"].tolist(),
                   "reward": v["next.reward"].tolist(), "reward_is_pad": v["next.reward_is_pad"].tolist()}
               for i, v in w.items()},
}))
"""


@pytest.fixture(scope="module")
def lerobot_python() -> str:
    return str(locked_venv("lerobot", "3.12", LOCK))


def _check(got: dict, ds, picks: list[int]) -> None:
    """LeRobot's view of ``ds`` against our own tables."""
    frames = ds.frame_table()  # in index order: one file per task, tasks in position order
    tasks = ds.tasks.to_pandas()
    assert got["version"] == "0.6.1"
    assert (got["len"], got["episodes"], got["tasks"]) == (
        ds.info["total_frames"],
        ds.info["total_episodes"],
        3,
    )
    for i in picks:
        item, row = got["items"][str(i)], frames.slice(i, 1).to_pylist()[0]
        for col in (C.INDEX, C.EPISODE_INDEX, C.TASK_INDEX, C.TASK_ID, C.HISTORY_INDEX):
            assert item[col] == row[col], (i, col)
        assert item[C.ACTION] == row[C.ACTION] and item[C.OBS] == row[C.OBS]
        assert item[C.REWARD] == pytest.approx(row[C.REWARD])
        # the task string is the row task_index of meta/tasks.parquet, for the env's task id
        assert item["task"] == tasks[C.TASK].iloc[row[C.TASK_INDEX]]
        assert tasks[C.TASK_ID].iloc[row[C.TASK_INDEX]] == row[C.TASK_ID]
        # delta_timestamps: earlier frames of the same episode, padded before its start
        step = row[C.FRAME_INDEX]
        want = [frames.slice(max(i + d, i - step), 1).to_pylist()[0][C.ACTION] for d in (-2, -1, 0)]
        assert got["window"][str(i)]["action"] == want
        assert got["window"][str(i)]["action_is_pad"] == [step < 2, step < 1, False]
        last = step == ds.horizon - 1
        assert got["window"][str(i)]["reward_is_pad"] == [False, last]
    E = ds.info["total_episodes"]
    assert got["subset_episodes"] == [3, 4, E - 1]
    assert got["subset_len"] == 3 * ds.horizon
    ids = ds.episodes.to_pandas().set_index(C.EPISODE_INDEX)
    names = {tasks[C.TASK].iloc[ids.loc[e, C.TASK_INDEX]] for e in (3, 4, E - 1)}
    assert set(got["subset_tasks"]) == names


def test_lerobot_reads_a_local_dataset(small_darkroom_batched, lerobot_python, hub_client):
    ds = small_darkroom_batched
    assert sorted(ds.lhf["tasks"]) == [3, 40, 62]  # sparse env task ids
    picks = sorted(np.random.default_rng(0).choice(ds.info["total_frames"], 12, replace=False))
    picks = [int(p) for p in picks] + [0, ds.info["total_frames"] - 1]
    proc = hub_client(
        None, READ, "local/darkroom", str(ds.root), json.dumps(picks), python=lerobot_python
    )
    got = _last_json(_ok(proc))
    _check(got, ds, picks)
    assert "Unknown fields in DatasetInfo" not in proc.stderr  # info.json is LeRobot's own


def test_lerobot_reads_a_pushed_dataset_and_the_card_snippet_runs(
    small_darkroom_batched, fake_hub, olah, lerobot_python, hub_client
):
    ds = small_darkroom_batched
    repo = "lhf-test/darkroom-lerobot"
    _ok(hub_client(fake_hub.endpoint, CLI, "push", str(ds.root), "--repo-id", repo))
    picks = [5, 777, ds.info["total_frames"] - 1]
    proc = hub_client(olah, READ, repo, "", json.dumps(picks), python=lerobot_python)
    _check(_last_json(_ok(proc)), ds, picks)

    # The card's LeRobot snippet, as pushed, runs as written.
    card = (fake_hub.repo_path("datasets", *repo.split("/")) / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", card, flags=re.S)
    snippet = next(b for b in blocks if "LeRobotDataset" in b)
    assert f'LeRobotDataset("{repo}")' in snippet
    out = _ok(hub_client(olah, snippet, python=lerobot_python))
    first = ds.tasks.to_pandas()[C.TASK].iloc[0]
    assert out.strip().splitlines()[-1].startswith(first)
