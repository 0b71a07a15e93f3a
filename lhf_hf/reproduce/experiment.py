"""Experiment specs: ``lhf_hf/reproduce/experiments/NAME.yaml`` -> ``Experiment`` (one per paper table).

A spec names the grid (envs x backbones), the data protocol, the LHF filter, the paper's relative
enhancements E for that table, and budget presets.  A preset overrides the sizes (histories per task,
training steps, model preset, evaluation episodes) and may narrow the grid; ``paper`` is the paper's
sizes, ``cpu`` the largest that fits a couple of hours on 2 cores, ``quick`` CI-sized.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from lhf_hf.constants import OBJECTIVES
from lhf_hf.envs import get_spec

#: The specs ship inside the package (package data), so ``lhf reproduce`` works from a wheel too.
EXPERIMENTS_DIR = Path(__file__).resolve().parent / "experiments"
PRESETS = ("quick", "cpu", "paper")

#: Defaults of every stage; a spec's top level, then its preset, override them.
DEFAULTS: dict = {
    "runs": 3,
    "collect": {
        "tasks": "train",
        "histories": 100,
        "steps": 1000,
        "protocol": "paper",
        "collector": "batched",
        "algo": "ppo",
    },
    "filter": {"strategy": "linear", "lam": 1.0, "alpha": 0.125},
    "train": {"preset": "paper", "max_steps": 2000, "batch_size": 64, "lr": 3e-3},
    "evaluate": {"episodes": 100, "plan_dicp": False},
}


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in (over or {}).items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


@dataclass(frozen=True)
class Experiment:
    """One paper experiment at one budget preset (``load_experiment(name, preset)``).

    name / title: the spec's file stem and a one-line description (the paper table it reproduces).
    envs / objectives: the grid; every cell trains a baseline and an LHF model per run.
    runs: independent runs; run r uses seed r and train/test split r (paper: 3).
    collect / filter / train / evaluate: stage settings (CollectConfig, FilterConfig, TrainConfig,
        EvalConfig fields; ``plan_dicp``: true evaluates DICP with planning (the paper's
        protocol), false without, "both" both ways from the same checkpoints, as two backbones
        "DICP" and "DICP + plan": with a small training budget the learned dynamics can be too poor
        to plan with, and the model-free row shows whether the policy itself learned).
    paper: the paper's E in percent, ``{env: {objective: value}}`` (None where it has none).
    budget: what the preset is, in words, against the paper's sizes (goes into the report).
    """

    name: str
    title: str
    preset: str
    envs: tuple[str, ...]
    objectives: tuple[str, ...]
    runs: int
    collect: dict
    filter: dict
    train: dict
    evaluate: dict
    paper: dict = field(default_factory=dict)
    paper_table: str = ""
    budget: str = ""

    def __post_init__(self) -> None:
        if self.preset not in PRESETS:
            raise ValueError(f"unknown preset {self.preset!r}: one of {PRESETS}")
        for env in self.envs:
            get_spec(env)  # unknown env ids fail here, with the registry's list
        bad = [o for o in self.objectives if o not in OBJECTIVES]
        if bad or not self.objectives or not self.envs:
            raise ValueError(f"{self.name}: objectives must be a non-empty subset of {OBJECTIVES}")
        if self.runs < 1:
            raise ValueError(f"{self.name}: runs must be >= 1, got {self.runs}")
        if self.evaluate.get("plan_dicp", False) not in (True, False, "both"):
            raise ValueError(
                f"{self.name}: evaluate.plan_dicp must be true, false or 'both', "
                f"got {self.evaluate['plan_dicp']!r}"
            )

    def dicp_plan_modes(self) -> tuple[bool, ...]:
        """The ``plan`` values DICP models are evaluated with (one evaluation stage each)."""
        mode = self.evaluate.get("plan_dicp", False)
        return (False, True) if mode == "both" else (bool(mode),)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def experiment_names() -> list[str]:
    return sorted(p.stem for p in EXPERIMENTS_DIR.glob("*.yaml"))


def load_experiment(
    name_or_path: str, preset: str = "quick", runs: int | None = None
) -> Experiment:
    """Read ``lhf_hf/reproduce/experiments/NAME.yaml`` (or a yaml path) at ``preset``."""
    path = Path(name_or_path)
    if not path.suffix:
        path = EXPERIMENTS_DIR / f"{name_or_path}.yaml"
    if not path.exists():
        raise KeyError(
            f"unknown experiment {name_or_path!r}: one of {experiment_names()} (or a yaml path)"
        )
    spec = yaml.safe_load(path.read_text()) or {}
    presets = spec.pop("presets", {}) or {}
    if preset not in presets:
        raise ValueError(f"{path.stem} has no preset {preset!r} (it has {sorted(presets)})")
    paper = spec.pop("paper", {}) or {}
    merged = _merge(_merge(DEFAULTS, spec), presets[preset])
    unknown = set(merged) - set(DEFAULTS) - {"title", "envs", "objectives", "paper_table", "budget"}
    if unknown:
        raise ValueError(f"{path}: unknown keys {sorted(unknown)}")
    return Experiment(
        name=path.stem,
        title=merged.get("title", path.stem),
        preset=preset,
        envs=tuple(merged["envs"]),
        objectives=tuple(merged["objectives"]),
        runs=int(runs if runs is not None else merged["runs"]),
        collect=merged["collect"],
        filter=merged["filter"],
        train=merged["train"],
        evaluate=merged["evaluate"],
        paper=paper,
        paper_table=merged.get("paper_table", ""),
        budget=merged.get("budget", ""),
    )
