"""What the ``lhf`` commands take besides the configs they run: output folders, inputs, Hub
targets.  With the configs, these dataclasses are where every command-line flag is defined (its type,
choices, default and help text): ``lhf_hf.cli.flags`` generates the flags from them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

from lhf_hf.errors import UserError

from .types import check_types

ExperimentPreset = Literal["quick", "cpu", "paper"]
EXPERIMENT_PRESETS: tuple[str, ...] = get_args(ExperimentPreset)


@dataclass(frozen=True)
class OutputOptions:
    """Where a command writes, and what it may do with what is there already.

    out: the folder to write.
    resume: continue an interrupted run in ``out``.
    overwrite: replace what ``out`` holds.
    progress: show progress bars.
    """

    out: str
    resume: bool = False
    overwrite: bool = False
    progress: bool = True

    def __post_init__(self) -> None:
        check_types(self)
        if self.resume and self.overwrite:
            raise UserError("resume and overwrite exclude each other")


@dataclass(frozen=True)
class FilterInputs:
    """What ``lhf filter`` reads, and the dataset it may also write.

    dataset: history dataset folder or Hub dataset repo ``ORG/NAME[@REV]``.
    materialize: also write the selected histories (with their repeats) as a dataset in this folder.
    """

    dataset: str
    materialize: str | None = None


DeriveOp = Literal["half"]


@dataclass(frozen=True)
class DeriveOptions:
    """A dataset derived from a history dataset.

    op: ``half``: the first ``fraction`` of every history, in whole episodes (the paper's
        half-history table).
    src: the source history dataset folder.
    fraction: the part of each history kept.
    """

    op: DeriveOp
    src: str
    fraction: float = 0.5


@dataclass(frozen=True)
class CompareOptions:
    """Evaluation runs to compare, paired by backbone.

    baseline: evaluation folders of models trained without LHF.
    lhf: evaluation folders of models trained with LHF.
    out: folder for ``compare.md``, ``compare.json`` and ``compare.png``; None prints the table only.
    overwrite: replace the comparison ``out`` holds.
    """

    baseline: list[str]
    lhf: list[str]
    out: str | None = None
    overwrite: bool = False


@dataclass(frozen=True)
class PushOptions:
    """One artifact folder pushed to a Hub repo.

    path: the artifact folder (``lhf collect`` / ``lhf filter`` / ``lhf train`` output).
    repo_id: the target repo ``ORG/NAME`` (created if absent).
    private: create the repo private.
    revision: the branch to commit to (created if absent); None = main.
    token: a write token; None = the logged-in one (``hf auth login`` or ``HF_TOKEN``).
    message: the commit message; None = one naming the artifact.
    source_repo: for a selection made from a local dataset: the Hub dataset repo
        ``ORG/NAME[@REV]`` that dataset was pushed to, checked to hold the same data, then named
        (at its commit) in the card's train command and the pushed record; None = the card says
        ``DATASET``.
    """

    path: str
    repo_id: str
    private: bool = False
    revision: str | None = None
    token: str | None = None
    message: str | None = None
    source_repo: str | None = None


@dataclass(frozen=True)
class ReproduceOptions:
    """One paper experiment, end to end.

    experiment: an experiment spec: a name (a file of ``lhf_hf/reproduce/experiments``, e.g.
        ``darkroom-main``) or the path of a yaml file.
    preset: the budget: ``quick`` (CI-sized), ``cpu`` (a couple of hours on 2 cores) or ``paper``.
    runs: independent runs; None = the preset's.
    out: report folder; None = ``results/EXPERIMENT-PRESET`` (a spec file named like a
        shipped spec has none: it names its own).
    work: the stage cache (datasets, checkpoints, evaluations), reused by later runs.
    jobs: stages run at once, each in its own process with one thread (2 on 2 cores: trainings
        finish 1.3x sooner); 1 = one after the other in this process.
    estimate: run nothing; print the stages, which are cached, and the estimated time of the rest
        on this machine (from the rates that finished stages recorded, or the shipped reference).
    objectives: only these of the spec's backbones (e.g. ``dicp``); their stages are the full
        table's, so a later full run reuses them; the report (default ``results/NAME-PRESET-dicp``)
        covers only them.  Unset: all.
    import_stages: folders of finished stages that ``--export-stages`` wrote (on another machine,
        or committed), copied into the work folder first (each checked whole before): their
        evaluations are not run again, nor the trainings they alone needed.  With ``--estimate``:
        imported (a write to the work folder), then estimated.  Put it after the experiment's name.
    export_stages: run nothing; copy the finished evaluations of this plan (and the records of its
        other finished stages) from the work folder into this folder, to commit or carry to
        another machine (~0.1 MB per evaluation; datasets and checkpoints are not copied).
    """

    experiment: str
    preset: ExperimentPreset = "quick"
    runs: int | None = None
    out: str | None = None
    work: str = "runs/reproduce"
    jobs: int = 1
    estimate: bool = False
    objectives: list[str] | None = None
    import_stages: list[str] | None = None
    export_stages: str | None = None

    def __post_init__(self) -> None:
        if self.jobs < 1:
            raise UserError(f"jobs must be >= 1, got {self.jobs}")
        if self.export_stages is not None and (self.estimate or self.import_stages):
            given = "--estimate" if self.estimate else "--import-stages"
            raise UserError(
                f"--export-stages runs nothing else: drop {given} (import, run or estimate with "
                "one call, export with another)"
            )
        if self.runs is not None and self.runs < 1:
            raise UserError(f"runs must be >= 1, got {self.runs}")
        for flag, folder in (("--out", self.out), ("--export-stages", self.export_stages)):
            if folder is not None and not folder.strip():  # '' would be the current folder
                raise UserError(f"{flag} is empty: name a folder")


@dataclass(frozen=True)
class EnvsOptions:
    """What ``lhf envs`` shows.

    json: print JSON instead of a table.
    oracle: also roll out the oracle on each env's test tasks (gridworlds: the exact oracle;
        Meta-World: its scripted policy with the goal revealed).
    split_seed: the train/test split seed of ``oracle``.
    metaworld_tasks: test tasks per Meta-World env under ``oracle`` (each takes ~1 s).
    """

    json: bool = False
    oracle: bool = False
    split_seed: int = 0
    metaworld_tasks: int = 2


@dataclass(frozen=True)
class VerifyOptions:
    """What ``lhf verify`` checks.

    path: an output folder of lhf (a dataset, selection, model, evaluation, comparison or report).
    """

    path: str


@dataclass(frozen=True)
class UpgradeOptions:
    """What ``lhf upgrade`` rewrites.

    path: a learning-history dataset folder in lhf's earlier layout (its env task numbers in
        ``task_index``), rewritten in place into LeRobot v3.0 as LeRobot's reader loads it.
    """

    path: str
