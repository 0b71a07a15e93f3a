"""Experiment specs: ``lhf_hf/reproduce/experiments/NAME.yaml`` -> ``Experiment`` (docs/reproduce.md,
``experiment.py``): the spec's top level <- one preset; what neither sets is the stage config's
default, and every stage's config is built at load, so a bad setting fails before anything runs.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from lhf_hf.configs import CollectConfig, EvalConfig, FilterConfig, TrainConfig
from lhf_hf.configs.commands import EXPERIMENT_PRESETS as PRESETS
from lhf_hf.configs.filter import READS as FILTER_READS
from lhf_hf.constants import OBJECTIVES
from lhf_hf.envs import get_spec
from lhf_hf.errors import UnknownNameError, UserError
from lhf_hf.evaluation.compare import backbone_of

#: The specs ship inside the package (package data), so ``lhf reproduce`` works from a wheel too.
EXPERIMENTS_DIR = Path(__file__).resolve().parent / "experiments"

#: Config fields the reproduction sets itself, per run / env / backbone (a spec may not).
SET_BY_RUN = {
    "collect": {"env_id", "seed", "split_seed"},
    "filter": {"seed"},
    "train": {"dataset", "selection", "out", "objective", "seed", "resume", "overwrite",
              "push_to_hub", "hub_private"},
    "evaluate": {"model", "out", "plan", "seed", "split_seed", "overwrite"},
}  # fmt: skip
#: Settings of a stage that are not config fields: the derived half dataset, the filter sweep,
#: per-backbone training settings, and how DICP is evaluated.
STAGE_EXTRAS = {
    "collect": {"half"},
    "filter": {"sweep"},
    "train": {"by_objective"},
    "evaluate": {"plan_dicp"},
}
CONFIGS = {
    "collect": CollectConfig,
    "filter": FilterConfig,
    "train": TrainConfig,
    "evaluate": EvalConfig,
}
#: Run r uses seed r and train/test split r; the paper reports 3-5 runs. A larger count is a typo
#: whose plan (tens of stages per run) would take minutes and gigabytes to build, even to estimate.
MAX_RUNS = 100
TOP_KEYS = {"title", "paper_table", "budget", "choices", "envs", "objectives", "runs", *CONFIGS}
#: How a spec's setting was chosen (``choices``; docs/reproduce.md): on the validation goals of the
#: train split, the paper's or the reference code's value, what the budget affords (cost, not
#: return), a design choice measured elsewhere, or on test goals (the goals tables report: said so
#: that a reader discounts it; tuning belongs on validation goals).
CHOSEN = ("validation", "paper", "reference", "budget", "design", "test")
#: ``EvalConfig`` fields that only apply with ``plan``: a spec's are left out of its model-free
#: evaluations (which ``plan_dicp: both`` runs from the same settings)
PLAN_SETTINGS = ("plan_dynamics", "plan_order", "plan_ties", "plan_gate", "plan_reward_threshold")
#: How a DICP model is evaluated (``evaluate.plan_dicp``, one evaluation stage each): ``none``
#: without planning, ``plan`` with the spec's planning settings (the reference planner unless the
#: spec sets a variant), ``gated`` with planning gated on a seen reward (a variant of ours).
#: ``plan:P`` / ``gated:P`` add a reward threshold (``plan_reward_threshold`` P, a variant of
#: ours), so one table holds the reference planner and a thresholded one from the same checkpoints.
#: ``true`` / ``false`` / ``both`` name ``[plan]`` / ``[none]`` / ``[none, plan]``.
PLAN_MODES = ("none", "plan", "gated")
_PLAN_ALIASES = {True: ("plan",), False: ("none",), "both": ("none", "plan")}


def _is_alias(modes) -> bool:
    return isinstance(modes, bool | str) and modes in _PLAN_ALIASES


def _split_mode(mode: str) -> tuple[str, float | None]:
    """``"gated:0.99"`` -> ``("gated", 0.99)``; ``"plan"`` -> ``("plan", None)``."""
    base, sep, threshold = mode.partition(":")
    if not sep:
        return base, None
    try:
        return base, float(threshold)
    except ValueError:
        return base, float("nan")  # refused by _valid_mode


def _valid_mode(mode) -> bool:
    if not isinstance(mode, str):
        return False
    base, p = _split_mode(mode)
    return base in PLAN_MODES and (p is None or base != "none" and 0 < p < 1)


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in (over or {}).items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _merge_train(top: dict, preset: dict) -> dict:
    """top level <- preset, a preset's shared setting replacing the top level's ``by_objective``
    one (the preset is the budget), its own ``by_objective`` last (null: drops the top's)."""
    out = _merge(top, preset)
    top_by, shared = top.get("by_objective"), set(preset) - {"by_objective"}
    if isinstance(top_by, dict) and "by_objective" in out and out["by_objective"] is not None:
        kept = {
            o: {k: v for k, v in s.items() if k not in shared} if isinstance(s, dict) else s
            for o, s in top_by.items()
        }
        over = preset.get("by_objective", {})
        out["by_objective"] = _merge(kept, over) if isinstance(over, dict) else over
    return out


def _check_keys(where: str, settings: dict, stage: str, extras=frozenset()) -> None:
    """Each key of ``settings`` is a field of the stage's config that the run does not set (or an
    extra)."""
    allowed = {f.name for f in dataclasses.fields(CONFIGS[stage])} - SET_BY_RUN[stage]
    if unknown := sorted(set(settings) - allowed - set(extras)):
        raise UserError(f"{where}.{unknown[0]} is not a setting of this stage (one of "
                        f"{sorted(allowed)}; the run sets {sorted(SET_BY_RUN[stage])})")  # fmt: skip


@dataclass(frozen=True)
class Experiment:
    """One paper experiment at one budget preset (``load_experiment(name, preset)``).

    spec: the name of a shipped spec, else the yaml's path as given (a report's command runs as
        written).  collect / filter / train / evaluate: fields of the stage's config, less what the
        run sets (``SET_BY_RUN``), plus ``STAGE_EXTRAS``.  paper: the paper's E in percent per env
        and backbone.  narrowed: the objectives are a subset of the spec's (``--objectives``).
    """

    name: str
    title: str
    preset: str
    envs: tuple[str, ...]
    objectives: tuple[str, ...]
    runs: int = 3
    collect: dict = field(default_factory=dict)
    filter: dict = field(default_factory=dict)
    train: dict = field(default_factory=dict)
    evaluate: dict = field(default_factory=dict)
    paper: dict = field(default_factory=dict)
    paper_table: str = ""
    budget: str = ""
    choices: dict = field(default_factory=dict)
    narrowed: bool = False
    spec: str = ""

    def __post_init__(self) -> None:
        name = self.name
        if self.preset not in PRESETS:
            raise UserError(f"unknown preset {self.preset!r}: one of {PRESETS}")
        for env in self.envs:
            get_spec(env)  # unknown env ids fail here, with the registry's list
        if not self.envs or not self.objectives or not set(self.objectives) <= set(OBJECTIVES):
            raise UserError(f"{name}: objectives must be a non-empty subset of {OBJECTIVES}")
        if not 1 <= self.runs <= MAX_RUNS:
            raise UserError(f"{name}: runs must be 1 .. {MAX_RUNS}, got {self.runs}")
        modes = self.evaluate.get("plan_dicp", False)
        what = (
            f"{name}: evaluate.plan_dicp must be true, false, 'both' or a list of "
            f"{', '.join(PLAN_MODES)}, plan:P or gated:P (P a reward threshold in (0, 1); each "
            "once)"
        )
        if not (_is_alias(modes) or isinstance(modes, list) and modes):
            raise UserError(f"{what}, got {modes!r}")
        if isinstance(modes, list):
            if bad := [m for m in modes if not _valid_mode(m)]:
                raise UserError(f"{what}; not a mode: {', '.join(map(repr, bad))}")
            seen = [_split_mode(m) for m in modes]  # "gated:0.99" and "gated:0.990" are one
            if twice := [m for i, m in enumerate(modes) if seen[i] in seen[:i]]:
                raise UserError(f"{what}; given twice: {', '.join(map(repr, twice))}")
        split = [_split_mode(m) for m in self.dicp_plan_modes()]
        if (
            any(b == "gated" for b, _ in split)
            and self.evaluate.get("plan_gate", "always") != "always"
        ):
            raise UserError(
                f"{name}: evaluate.plan_gate {self.evaluate['plan_gate']!r} gates every planned "
                "evaluation: with plan_dicp's 'gated' leave plan_gate out (plan = the reference)"
            )
        if any(p is not None for _, p in split) and self.evaluate.get("plan_reward_threshold"):
            raise UserError(
                f"{name}: evaluate.plan_reward_threshold applies to every planned evaluation: with "
                "plan_dicp's MODE:P thresholds leave it out (plan = the reference)"
            )
        for stage in CONFIGS:
            _check_keys(f"{name}: {stage}", getattr(self, stage), stage, STAGE_EXTRAS[stage])
        by_objective = self.train.get("by_objective") or {}  # null: none (a preset may cancel)
        if not isinstance(by_objective, dict):
            raise UserError(f"{name}: train.by_objective must map backbones "
                            f"({', '.join(OBJECTIVES)}) to settings, got {by_objective!r}")  # fmt: skip
        for objective, settings in by_objective.items():
            where = f"{name}: train.by_objective.{objective}"
            if objective not in OBJECTIVES:
                raise UserError(
                    f"{where}: {objective!r} is not a backbone ({', '.join(OBJECTIVES)})"
                )
            if not isinstance(settings, dict):
                raise UserError(
                    f"{where} must be a mapping of TrainConfig settings, got {settings!r}"
                )
            _check_keys(where, settings, "train")
        self._check_choices()
        sweep = self.filter.get("sweep")
        if sweep is not None and (
            not isinstance(sweep, dict) or set(sweep) != {"key", "values"} or not sweep["values"]
        ):
            raise UserError(f"{name}: filter.sweep must be {{key: FIELD, values: [...]}}")
        # Every config of every stage, built now, each error named by its spec and stage: the
        # shared train settings alone first (their errors are theirs), then every backbone the
        # spec trains or sets a budget for.
        shared = {k: v for k, v in self.train.items() if k != "by_objective"}
        self._build("collect", lambda: [self.collect_config(env, 0) for env in self.envs])
        self._build("filter", self._checked_filter_arms)
        self._build(
            "train",
            lambda: TrainConfig(dataset="-", objective=self.objectives[0], out="-", **shared),
        )
        for o in dict.fromkeys([*self.objectives, *by_objective]):
            stage = f"train.by_objective.{o}" if o in by_objective else "train"
            self._build(
                stage, lambda o=o: self.train_config(o, 0, dataset="-", selection=None, out="-")
            )
        for plan in self.dicp_plan_modes():
            self._build("evaluate", lambda p=plan: self.eval_config(0, model="-", out="-", plan=p))

    def _check_choices(self) -> None:
        if not isinstance(self.choices, dict):
            raise UserError(
                f"{self.name}: choices must map settings to how they were chosen, got a "
                f"{type(self.choices).__name__}"
            )
        for setting, how in self.choices.items():
            where = f"{self.name}: choices.{setting}"
            if not isinstance(how, dict) or set(how) != {"chosen", "evidence"}:
                raise UserError(f"{where} must be {{chosen: ..., evidence: ...}}, got {how!r}")
            if how["chosen"] not in CHOSEN:
                raise UserError(f"{where}.chosen must be one of {CHOSEN}, got {how['chosen']!r}")
            if not isinstance(how["evidence"], str) or not how["evidence"].strip():
                raise UserError(
                    f"{where}.evidence must be a text saying what shows it (a file or a command), "
                    f"got {how['evidence']!r}"
                )
            self.setting(setting, where)

    def setting(self, path: str, where: str = ""):
        """The value of a dotted setting the spec sets (``train.by_objective.dicp.max_steps``), or
        of ``runs``, ``envs`` or ``objectives``."""
        if path in ("runs", "envs", "objectives"):
            return getattr(self, path)
        stage, *keys = str(path).split(".")
        found = getattr(self, stage) if stage in CONFIGS else None
        for key in keys:
            if not isinstance(found, dict) or key not in found:
                raise UserError(
                    f"{where or path}: the spec sets no {path!r} at this preset (a choice names "
                    "runs, envs, objectives or a setting of collect, filter, train or evaluate "
                    "that it sets)"
                )
            found = found[key]
        if not keys:
            raise UserError(f"{where or path}: name a setting, e.g. train.max_steps")
        return found

    def _build(self, stage: str, build) -> None:
        try:
            build()
        except (ValueError, TypeError, KeyError) as exc:
            msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
            raise UserError(f"{self.name}: {stage}: {msg}") from None

    def _checked_filter_arms(self) -> None:
        """The arms of run 0 differ, and every env's R_max is known (else the first filter would
        fail, after the collection)."""
        arms = self.filter_arms(0)
        if len({cfg for _, cfg in arms}) != len(arms):
            raise UserError("the sweep's values repeat (the same config twice)")
        for env in self.envs:
            if get_spec(env).optimal_returns is None and any(c.r_max is None for _, c in arms):
                raise UserError(
                    f"{env} has no known optimal return: set filter: {{r_max: ...}} (the "
                    "maximal episode return its scores divide by)"
                )

    # ---- the configs of the stages (one source: the config dataclasses)
    def collect_config(self, env: str, run: int) -> CollectConfig:
        settings = {k: v for k, v in self.collect.items() if k != "half"}
        # the train split by default: the models are evaluated on the run's unseen (test) tasks
        return CollectConfig(env_id=env, seed=run, split_seed=run, **{"tasks": "train", **settings})

    @property
    def half(self) -> bool:
        return bool(self.collect.get("half", False))

    def filter_arms(self, run: int) -> list[tuple[str, FilterConfig]]:
        """``[(arm name, FilterConfig)]``: ``lhf``, or one arm per value of the sweep."""
        base = {k: v for k, v in self.filter.items() if k != "sweep"}
        sweep = self.filter.get("sweep")
        if not sweep:
            return [("lhf", FilterConfig(**base, seed=run))]
        key = sweep["key"]
        if key in SET_BY_RUN["filter"]:
            raise UserError(f"filter.sweep.key {key!r} is set by each run (run r uses seed r)")
        if key not in {f.name for f in dataclasses.fields(FilterConfig)}:
            raise UserError(f"filter.sweep.key {key!r} is not a FilterConfig field")
        strategy = base.get("strategy", FilterConfig.strategy)
        if key != "strategy" and key not in FILTER_READS.get(strategy, {key}):
            raise UserError(
                f"filter.sweep.key {key!r}: the {strategy!r} strategy does not read it, so every "
                f"arm would select the same histories (it reads {sorted(FILTER_READS[strategy])})"
            )
        return [(f"{key}={v}", FilterConfig(**{**base, key: v}, seed=run)) for v in sweep["values"]]

    def train_config(
        self,
        objective: str,
        run: int,
        *,
        dataset: str,
        selection: str | None,
        out: str,
        resume=False,
    ) -> TrainConfig:
        return TrainConfig(
            dataset=dataset,
            selection=selection,
            objective=objective,
            out=out,
            seed=run,
            resume=resume,
            overwrite=not resume,
            **train_settings(self.train, objective),
        )

    def eval_config(self, run: int, *, model: str, out: str, plan: str = "none") -> EvalConfig:
        """Run ``run``'s evaluation config in plan mode ``plan`` (``PLAN_MODES``, ``MODE:P``)."""
        settings = {k: v for k, v in self.evaluate.items() if k != "plan_dicp"}
        base, threshold = _split_mode(plan)
        if base == "none":  # planning settings belong to the planned evaluations only
            settings = {k: v for k, v in settings.items() if k not in PLAN_SETTINGS}
        if base == "gated":
            settings["plan_gate"] = "reward_seen"
        if threshold is not None:
            settings["plan_reward_threshold"] = threshold
        # a stage folder is the cache's own: a half-written evaluation in it is replaced
        return EvalConfig(
            model=model, out=out, plan=base != "none", seed=run, overwrite=True, **settings
        )

    def dicp_plan_modes(self) -> tuple[str, ...]:
        """The plan modes DICP models are evaluated in (one evaluation stage each)."""
        modes = self.evaluate.get("plan_dicp", False)
        return _PLAN_ALIASES[modes] if _is_alias(modes) else tuple(modes)

    def column(self, objective: str, plan: str = "none") -> str:
        """The table row ``compare`` gives this backbone's evaluations (``backbone_of``)."""
        cfg = self.eval_config(0, model="-", out="-", plan=plan)
        return backbone_of({"objective": objective, "config": cfg.to_dict()})

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def train_settings(train: dict, objective: str) -> dict:
    """One backbone's ``train`` settings: the shared ones, then its ``by_objective`` overrides."""
    settings = {k: v for k, v in train.items() if k != "by_objective"}
    settings.update((train.get("by_objective") or {}).get(objective) or {})
    return settings


def experiment_names() -> list[str]:
    return sorted(p.stem for p in EXPERIMENTS_DIR.glob("*.yaml"))


def shadows_shipped(name: str, spec: str | None) -> bool:
    """A spec file outside the package named like a shipped spec (no default report folder)."""
    return bool(spec) and spec != name and name in experiment_names()  # '': not recorded


def spec_path(name_or_path: str | Path) -> Path:
    """The yaml file of a shipped experiment's name, or the given path (which must exist)."""
    path = Path(name_or_path)
    folder = f"{str(name_or_path)!r} is a folder: a spec is a yaml file or a shipped name"
    if path.suffix:
        if path.is_dir():
            raise KeyError(folder)
        if not path.is_file():
            raise UnknownNameError(f"no such spec file: {str(name_or_path)!r}")
        return path
    shipped = EXPERIMENTS_DIR / f"{name_or_path}.yaml"
    if shipped.exists():  # a shipped name wins over a folder or file of that name here
        return shipped
    if path.is_dir():
        raise KeyError(folder)
    # a file without a suffix is not taken for a spec: say so rather than "unknown"
    hint = " (a spec file needs a .yaml or .yml suffix)" if path.is_file() else " (or a yaml path)"
    raise UnknownNameError(
        f"unknown experiment {name_or_path!r}: one of {experiment_names()}{hint}"
    )


def _leaves(value, prefix: str) -> list[str]:
    """The dotted paths of a nested mapping's values (``train.by_objective.dicp.max_steps``)."""
    if not isinstance(value, dict) or not value:
        return [prefix]
    return [p for k, v in value.items() for p in _leaves(v, f"{prefix}.{k}")]


def _check_complete(where: str, preset: dict, choices: dict) -> None:
    """A preset that says how its settings were chosen says it for every setting it sets (its
    ``budget`` text aside): a reviewer reads the list as complete (issue 55)."""
    sets = [p for key, v in preset.items() if key not in ("budget", "choices", "title")
            for p in (_leaves(v, key) if key in CONFIGS else [key])]  # fmt: skip
    missing = [p for p in sets if not any(p == c or p.startswith(f"{c}.") for c in choices)]
    if missing:
        raise UserError(
            f"{where}: its choices say how some settings were chosen, so they must say it for "
            f"every setting the preset sets; none for {', '.join(missing)}"
        )


def load_experiment(
    name_or_path: str,
    preset: str = "quick",
    runs: int | None = None,
    objectives: list[str] | tuple[str, ...] | None = None,
) -> Experiment:
    """Read ``lhf_hf/reproduce/experiments/NAME.yaml`` (or a yaml path) at ``preset``;
    ``objectives``: only these of the spec's backbones (None: all)."""
    path = spec_path(name_or_path)
    try:
        spec = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise UserError(f"{path} is not valid YAML: {exc}") from None
    if not isinstance(spec, dict):
        raise UserError(f"{path}: a spec is a mapping of settings, got a {type(spec).__name__}")
    presets = spec.pop("presets", {}) or {}
    if not isinstance(presets, dict) or not all(isinstance(v, dict) for v in presets.values()):
        raise UserError(f"{path}: presets must map each preset name to its settings")
    if preset not in presets:
        raise UserError(f"{path.stem} has no preset {preset!r} (it has {sorted(presets)})")
    paper = spec.pop("paper", {}) or {}
    merged = _merge(spec, presets[preset])
    if isinstance(spec.get("train"), dict) and isinstance(presets[preset].get("train"), dict):
        merged["train"] = _merge_train(spec["train"], presets[preset]["train"])
    if unknown := set(merged) - TOP_KEYS:
        raise UserError(f"{path}: unknown keys {sorted(unknown)} (one of {sorted(TOP_KEYS)})")
    for key, kind in [*((stage, dict) for stage in CONFIGS), ("envs", list), ("objectives", list)]:
        if not isinstance(merged.get(key, kind()), kind):
            what = "a mapping of settings" if kind is dict else f"a list, e.g. [{merged[key]}]"
            raise UserError(f"{path}: {key} must be {what}")
    if isinstance(presets[preset].get("choices"), dict):
        _check_complete(f"{path.stem} --preset {preset}", presets[preset], merged["choices"])
    if runs is not None:
        if int(runs) != merged.get("runs", Experiment.runs) and isinstance(
            merged.get("choices"), dict
        ):
            merged["choices"].pop("runs", None)  # the spec's reason is for its own count
        merged["runs"] = int(runs)
    shipped = path.resolve() == (EXPERIMENTS_DIR / f"{path.stem}.yaml").resolve()
    exp = Experiment(
        name=path.stem,
        spec=path.stem if shipped else str(name_or_path),
        title=merged.pop("title", path.stem),
        preset=preset,
        envs=tuple(merged.pop("envs", ())),
        objectives=tuple(merged.pop("objectives", ())),
        paper=paper,
        **merged,
    )
    if objectives is None or set(objectives) == set(exp.objectives):
        return exp
    unknown = sorted(set(objectives) - set(exp.objectives))
    if unknown or not objectives:
        raise UserError(
            f"{exp.name} has no backbone {unknown[0] if unknown else '(none given)'!r}: "
            f"choose among {list(exp.objectives)}"
        )
    keep = tuple(o for o in exp.objectives if o in objectives)  # the spec's order
    # the choices of the backbones left out (and of the grid itself) do not describe this table
    moot = ("objectives", *(f"train.by_objective.{o}." for o in exp.objectives if o not in keep))
    moot += () if "dicp" in keep else ("evaluate.plan_dicp",)
    choices = {k: c for k, c in exp.choices.items() if not k.startswith(moot)}
    return dataclasses.replace(exp, objectives=keep, narrowed=True, choices=choices)
