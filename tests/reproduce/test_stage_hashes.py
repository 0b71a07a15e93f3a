"""The stage hashes are pinned: a changed hash re-runs every committed table's stages and orphans
the committed exports (``--import-stages``), so a refactor of the planning must keep them."""

from __future__ import annotations

import hashlib
import importlib
import json

import pytest
import yaml

from lhf_hf.modeling import attention_kernel
from lhf_hf.reproduce import load_experiment, plan_stages
from tests.reproduce.test_reproduce import TINY

# every kind of stage and every branch of a stage's config: a derived half, a filter sweep, two
# backbones with a per-backbone budget, DICP evaluated with and without a gated planner
SPEC = {
    **TINY,
    "objectives": ["ad", "dicp"],
    "collect": {"collector": "batched", "half": True},
    "filter": {"strategy": "linear", "sweep": {"key": "lam", "values": [0, 2]}},
    "train": {"by_objective": {"dicp": {"max_steps": 6}}},
    "evaluate": {"plan_dicp": "both", "plan_gate": "reward_seen"},
}
#: (ppo backend, attention code) -> the first stage of each kind, the digest of the whole plan's
#: hashes, and those of two shipped specs at the cpu preset (a batched and an SB3 collection)
PINNED = {
    "torch": (
        {"collect": "7d7be3a4270e", "derive": "a7910b8e97dc", "filter": "ecf6cb53f161",
         "train": "f2f92ff6c193", "evaluate": "3ad4f78f08ee"},
        "e6b79293b51d9887",
        {"darkroom-main": (48, "de80be082601dcf7"), "metaworld-sac": (60, "151a50d1da17e056")},
    ),
    "kernel": (
        {"collect": "064a4099ef67", "derive": "303f4a2fcde0", "filter": "337d5f4bd84a",
         "train": "dc7ae205d9b2", "evaluate": "29a9056fd9d3"},
        "b18e9d65a665783c",
        {"darkroom-main": (48, "0265f2aed4e9b6b9"), "metaworld-sac": (60, "b612d46b86fb8a3f")},
    ),
}  # fmt: skip


def _digest(stages) -> str:
    return hashlib.sha256(" ".join(s.hash for s in stages).encode()).hexdigest()[:16]


@pytest.mark.parametrize("code", sorted(PINNED))
def test_stage_hashes_are_unchanged(tmp_path, monkeypatch, code):
    # what this machine would decide (a timing, a compiler) fixed: the hash names the decision
    rep = importlib.import_module("lhf_hf.reproduce.reproduce")  # the module, not the function
    monkeypatch.setattr(rep, "resolve_ppo_backend", lambda cfg: code)
    monkeypatch.setattr(attention_kernel, "available", lambda: None if code == "kernel" else "no")
    (tmp_path / "pin.yaml").write_text(yaml.safe_dump(json.loads(json.dumps(SPEC))))
    first, plan, shipped = PINNED[code]
    stages, _ = plan_stages(load_experiment(str(tmp_path / "pin.yaml"), "quick"), tmp_path)
    found: dict[str, str] = {}
    for s in stages:
        found.setdefault(s.kind, s.hash[:12])
    assert found == first
    assert len(stages) == 38 and _digest(stages) == plan
    # Changed on purpose: the beam search's planned evaluations name their tie order (`plan_ties`,
    # the reference's `index` now; they ran with ties by policy before), gridworld DICP trainings
    # with an unset reward weighting name the resolved one (now the reference's `data`, was
    # `actions`), and darkroom-main's cpu preset evaluates DICP without planning and with the
    # reference planner only (60 -> 48 stages: its gated variants left out, the rest unchanged).
    # Model-free evaluations, AD/DPT stages and Meta-World's (greedy search, weighting `data`
    # either way) keep their hashes (the first stage of each kind above; metaworld-sac's digest).
    for name, (n, digest) in shipped.items():
        stages, _ = plan_stages(load_experiment(name, "cpu"), tmp_path)
        assert (len(stages), _digest(stages)) == (n, digest), name
