"""lhf reproduce: experiment specs, stage caching by config hash, seeds/splits per run, the report."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from lhf_hf.cli.main import main
from lhf_hf.configs import CollectConfig, EvalConfig, FilterConfig, TrainConfig
from lhf_hf.errors import UserError
from lhf_hf.reproduce import (
    estimate_experiment,
    experiment_names,
    load_experiment,
    plan_stages,
    reproduce,
)
from lhf_hf.reproduce.experiment import EXPERIMENTS_DIR
from lhf_hf.reproduce.report import verdict

TINY = {
    "title": "tiny",
    "paper_table": "a test",
    "envs": ["darkroom"],
    "objectives": ["ad"],
    "collect": {"collector": "batched"},
    "paper": {"darkroom": {"ad": 25.1}},
    "presets": {
        "quick": {
            "runs": 2,
            "collect": {"tasks": "train:2", "histories": 4, "steps": 200},
            "train": {"preset": "tiny", "max_steps": 4, "batch_size": 4, "save_steps": 4},
            "evaluate": {"episodes": 2},
        }
    },
}


def _spec(tmp_path: Path, spec: dict, name: str = "tiny") -> str:
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(spec))
    return str(path)


@pytest.mark.slow
def test_every_shipped_experiment_loads_at_every_preset(tmp_path):
    names = experiment_names()
    for required in ("darkroom-main", "darkroom-noisy", "darkroom-half", "darkroom-lightweight",
                     "darkroom-lambda", "darkroom-softmax", "metaworld-ml1", "metaworld-sac"):  # fmt: skip
        assert required in names
    for name in names:
        for preset in ("quick", "cpu", "paper"):
            exp = load_experiment(name, preset)
            stages, evals = plan_stages(exp, tmp_path)
            # every (env, arm, backbone) cell has one evaluation per run (DICP: per planning mode)
            for (_, _, obj), v in evals.items():
                modes = exp.dicp_plan_modes() if obj == "dicp" else ("none",)
                assert len(v) == exp.runs * len(modes)
            assert len({s.hash for s in stages}) == len(stages)  # no two stages share a folder
    main = load_experiment("darkroom-main", "paper")
    assert main.paper["darkroom"] == {"ad": 25.1, "dicp": 15.2, "dpt": 3.5}
    assert main.envs == ("darkroom", "darkroom-permuted", "darkroom-large", "dark-key-to-door")
    assert load_experiment("darkroom-main", "quick").envs == ("darkroom",)
    assert load_experiment("darkroom-main", "cpu", runs=5).runs == 5
    for runs in (0, 101, 1_000_000):  # refused before any stage is planned
        with pytest.raises(ValueError, match=r"runs must be 1 \.\. 100"):
            load_experiment("darkroom-main", "quick", runs=runs)


@pytest.mark.parametrize("preset", ["quick", "cpu", "paper"])
def test_the_independent_arm_is_the_main_table_but_its_collection(preset):
    # Read beside darkroom-main, the two arms may differ in how the histories were made and in
    # nothing else (an evaluation with 1 rollout and ungated planning once slipped in here).
    main = load_experiment("darkroom-main", preset)
    arm = load_experiment("darkroom-main-independent", preset)
    for name in ("envs", "objectives", "runs", "filter", "train", "evaluate", "paper"):
        assert getattr(arm, name) == getattr(main, name), name
    assert arm.collect == {**main.collect, "protocol": "independent"}
    assert main.collect["protocol"] == "paper"
    if preset == "cpu":  # the other Darkroom tables evaluate as the main one does
        for other in ("darkroom-noisy", "darkroom-half", "darkroom-lightweight"):
            assert load_experiment(other, preset).evaluate == main.evaluate, other


def test_spec_errors(tmp_path):
    with pytest.raises(KeyError, match="unknown experiment 'nope'"):
        load_experiment("nope")
    with pytest.raises(KeyError, match="no such spec file: '.*/missing.yaml'"):
        load_experiment(str(tmp_path / "missing.yaml"))
    (tmp_path / "d.yaml").mkdir()
    for folder in (tmp_path, tmp_path / "d.yaml"):
        with pytest.raises(KeyError, match="is a folder: a spec is a yaml file or a shipped name"):
            load_experiment(str(folder))
    (tmp_path / "nosuffix").write_text(yaml.safe_dump(TINY))
    with pytest.raises(KeyError, match=r"needs a \.yaml or \.yml suffix"):
        load_experiment(str(tmp_path / "nosuffix"))
    with pytest.raises(ValueError, match="has no preset 'cpu'"):
        load_experiment(_spec(tmp_path, TINY), "cpu")
    with pytest.raises(ValueError, match="unknown keys"):
        load_experiment(_spec(tmp_path, {**TINY, "colect": {}}, "typo"), "quick")
    with pytest.raises(KeyError, match="unknown env"):
        load_experiment(_spec(tmp_path, {**TINY, "envs": ["darkroom-xl"]}, "env"), "quick")
    with pytest.raises(ValueError, match="objectives"):
        load_experiment(_spec(tmp_path, {**TINY, "objectives": ["bc"]}, "obj"), "quick")
    with pytest.raises(ValueError, match="plan_dicp must be true, false, 'both' or a list"):
        load_experiment(_spec(tmp_path, {**TINY, "evaluate": {"plan_dicp": "yes"}}, "pl"), "quick")
    # an env without a known optimal return needs filter.r_max, named at load, not after collecting
    mw = {**TINY, "envs": ["metaworld-reach-wall"], "collect": {"collector": "sb3"}}
    with pytest.raises(
        ValueError,
        match=r"mw: filter: metaworld-reach-wall has no known optimal return: set filter",
    ):
        load_experiment(_spec(tmp_path, mw, "mw"), "quick")
    exp = load_experiment(_spec(tmp_path, {**mw, "filter": {"r_max": 1000}}, "mw2"), "quick")
    assert exp.filter_arms(0)[0][1].r_max == 1000


@pytest.mark.parametrize(
    "stage, settings, message",
    [
        ("train", {"lerning_rate": 1e-3}, "train.lerning_rate is not a setting of this stage"),
        ("collect", {"seed": 3}, "collect.seed is not a setting"),  # the run sets it
        ("evaluate", {"plan": True}, "evaluate.plan is not a setting"),  # plan_dicp says it
        ("collect", {"histories": 0}, "CollectConfig.histories must be >= 1"),
        ("train", {"lr": -1.0}, "TrainConfig.lr must be > 0"),
        ("filter", {"strategy": "greedy"}, "FilterConfig.strategy must be one of"),
        ("evaluate", {"context": "all"}, "EvalConfig.context must be one of"),
        ("filter", {"sweep": {"key": "lamda", "values": [1]}}, "sweep.key 'lamda'"),
        ("filter", {"sweep": {"key": "seed", "values": [1]}}, "set by each run"),
        ("filter", {"sweep": {"key": "lam", "values": [1, 1.0]}}, "values repeat"),
        (
            "filter",
            {"sweep": {"key": "alpha", "values": [0.5, 1]}},
            "'linear' strategy does not read",
        ),
        (
            "filter",
            {"strategy": "none", "sweep": {"key": "lam", "values": [0, 1]}},
            "'none' strategy",
        ),
        ("collect", {"histories": 2.5}, r"collect: CollectConfig.histories must be an integer"),
        ("train", {"lr": "1e-3"}, r"TrainConfig.lr must be a number, got '1e-3' \(in YAML"),
        ("evaluate", {"split_seed": 5}, "evaluate.split_seed is not a setting"),  # run r: split r
        ("collect", {"ppo": {"nstep": 3}}, "CollectConfig.ppo: unknown setting 'nstep'"),
        ("train", {"by_objective": {"bc": {"max_steps": 5}}}, "'bc' is not a backbone"),
        ("train", {"by_objective": {"dicp": 5}}, "by_objective.dicp must be a mapping"),
        ("train", {"by_objective": [1]}, r"by_objective must map backbones .* got \[1\]"),
        # checked although the spec (objectives: [ad]) does not train DICP
        (
            "train",
            {"by_objective": {"dicp": {"lr": -1.0}}},
            "by_objective.dicp: TrainConfig.lr must be > 0",
        ),
        (
            "train",
            {"by_objective": {"dicp": {"max_step": 5}}},
            "by_objective.dicp.max_step is not a setting",
        ),
    ],
)
def test_a_bad_stage_setting_fails_at_load(tmp_path, stage, settings, message):
    """Typos and bad values in any stage, top level or preset, fail before anything runs."""
    top = json.loads(json.dumps(TINY))
    top[stage] = {**top.get(stage, {}), **settings}
    for key in settings:  # the preset must not override what is tested at the top level
        top["presets"]["quick"].get(stage, {}).pop(key, None)
    with pytest.raises(ValueError, match=message):
        load_experiment(_spec(tmp_path, top, "top"), "quick")
    preset = json.loads(json.dumps(TINY))
    preset["presets"]["quick"][stage] = {**preset["presets"]["quick"].get(stage, {}), **settings}
    with pytest.raises(ValueError, match=message):
        load_experiment(_spec(tmp_path, preset, "preset"), "quick")


def test_malformed_specs_are_one_clear_error(tmp_path):
    bad = tmp_path / "broken.yaml"
    bad.write_text("title: [unclosed\n")
    with pytest.raises(ValueError, match="broken.yaml is not valid YAML"):
        load_experiment(str(bad))
    bad.write_text("- a\n- b\n")
    with pytest.raises(ValueError, match="a spec is a mapping of settings, got a list"):
        load_experiment(str(bad))
    with pytest.raises(ValueError, match=r"envs must be a list, e.g. \[darkroom\]"):
        load_experiment(_spec(tmp_path, {**TINY, "envs": "darkroom"}, "s"), "quick")


def test_stage_configs_take_the_config_defaults(tmp_path):
    """What a spec leaves out is the config dataclass's default: one set of defaults."""
    exp = load_experiment(_spec(tmp_path, TINY), "quick")
    col = exp.collect_config("darkroom", 1)
    assert isinstance(col, CollectConfig)
    assert (col.seed, col.split_seed, col.collector, col.protocol) == (1, 1, "batched", "paper")
    assert col.noisy_fraction == CollectConfig(env_id="darkroom").noisy_fraction
    assert col.tasks == CollectConfig(env_id="darkroom", tasks="train:2", split_seed=1).tasks
    ((arm, flt),) = exp.filter_arms(1)
    assert arm == "lhf" and flt == FilterConfig(seed=1)
    tr = exp.train_config("ad", 1, dataset="d", selection=None, out="o")
    assert tr == TrainConfig(dataset="d", objective="ad", out="o", seed=1, overwrite=True,
                             preset="tiny", max_steps=4, batch_size=4, save_steps=4)  # fmt: skip
    # train.by_objective overrides the shared settings for one backbone only
    spec = json.loads(json.dumps(TINY))
    spec["presets"]["quick"]["train"]["by_objective"] = {"dicp": {"max_steps": 8}}
    per = load_experiment(_spec(tmp_path, spec, "per"), "quick")
    assert per.train_config("ad", 1, dataset="d", selection=None, out="o") == tr
    assert per.train_config("dicp", 1, dataset="d", selection=None, out="o").max_steps == 8
    # top level <- preset: a preset's shared setting replaces the top level's per-backbone one (the
    # preset is the budget), its own by_objective applies last, and null there drops the top's
    spec = json.loads(json.dumps(TINY))
    spec["train"] = {"by_objective": {"dicp": {"max_steps": 50, "lr": 0.01}}}
    layered = load_experiment(_spec(tmp_path, spec, "layered"), "quick")
    dicp = layered.train_config("dicp", 1, dataset="d", selection=None, out="o")
    assert (dicp.max_steps, dicp.lr) == (4, 0.01)  # the preset sets max_steps: 4
    spec["presets"]["quick"]["train"]["by_objective"] = {"dicp": {"max_steps": 6}}
    layered = load_experiment(_spec(tmp_path, spec, "layered"), "quick")
    dicp = layered.train_config("dicp", 1, dataset="d", selection=None, out="o")
    assert (dicp.max_steps, dicp.lr) == (6, 0.01)
    spec["presets"]["quick"]["train"]["by_objective"] = None
    layered = load_experiment(_spec(tmp_path, spec, "layered"), "quick")
    dicp = layered.train_config("dicp", 1, dataset="d", selection=None, out="o")
    assert (dicp.max_steps, dicp.lr) == (4, tr.lr)
    assert exp.eval_config(1, model="m", out="o", plan="none") == EvalConfig(
        model="m", out="o", seed=1, episodes=2, overwrite=True
    )


def test_dicp_both_evaluates_each_checkpoint_with_and_without_planning(tmp_path):
    dicp = {**TINY, "objectives": ["ad", "dicp"], "paper": {"darkroom": {"ad": 25.1, "dicp": 15.2}}}
    both = load_experiment(_spec(tmp_path, {**dicp, "evaluate": {"plan_dicp": "both"}}, "b"))
    plan = load_experiment(_spec(tmp_path, {**dicp, "evaluate": {"plan_dicp": True}}, "p"))
    assert both.dicp_plan_modes() == ("none", "plan") and plan.dicp_plan_modes() == ("plan",)
    stages_b, evals_b = plan_stages(both, tmp_path)
    stages_p, evals_p = plan_stages(plan, tmp_path)
    ev = evals_b[("darkroom", "baseline", "dicp")]  # 2 runs x 2 modes, run by run
    assert [(s.config["seed"], s.config["plan"]) for s in ev] == [
        (0, False), (0, True), (1, False), (1, True)
    ]  # fmt: skip
    assert ev[0].config["model"] == ev[1].config["model"]  # the same checkpoint
    # the planned evaluations are the planning-only spec's stages: switching to "both" reuses them
    assert [s.hash for s in ev if s.config["plan"]] == [
        s.hash for s in evals_p[("darkroom", "baseline", "dicp")]
    ]
    assert len(stages_b) == len(stages_p) + 4  # + one model-free evaluation per DICP model
    assert all(len(evals_b[("darkroom", a, "ad")]) == 2 for a in ("baseline", "lhf"))
    # the report has one column per DICP mode, the paper's (planned) value beside both
    from lhf_hf.reproduce.report import columns, readings, render_report

    def row(backbone, e, diff_ci):
        return {"backbone": backbone, "E": e, "E_std": 0.01, "diff": 1.0, "diff_ci95": diff_ci,
                "baseline_mean": 5.0, "baseline_std": 0.1, "lhf_mean": 5.0 * (1 + e),
                "lhf_std": 0.1, "baseline_final": 6.0, "lhf_final": 7.0, "runs_baseline": 2,
                "runs_lhf": 2}  # fmt: skip

    rows = [row("AD", 0.2, [0.4, 1.6]), row("DICP", 0.1, [-0.3, 2.0]),
            row("DICP + plan", -0.5, [-2.0, -0.5])]  # fmt: skip
    cells = [{"env_id": "darkroom", "arm": "lhf", "rows": rows}]
    assert columns(both) == ["AD", "DICP", "DICP + plan"] and columns(plan) == ["AD", "DICP + plan"]
    found = readings(both, cells)
    assert [(r["label"], r["column"], r["row"]["E"]) for r in found] == [
        ("darkroom", "AD", 0.2), ("darkroom", "DICP", 0.1), ("darkroom", "DICP + plan", -0.5)
    ]  # fmt: skip
    # the paper's DICP is the reference planner's: beside `DICP + plan` only, not the policy alone
    assert [r["paper"] for r in found] == [25.1, None, 15.2]
    assert [r["verdict"] for r in found] == ["helps", "no clear effect (the paired return "
                                             "difference's 95% CI spans 0)", "hurts"]  # fmt: skip
    # a backbone the cell lacks is a column without a reading
    (missing,) = [r for r in readings(both, [{**cells[0], "rows": rows[:1]}]) if r["row"] is None][
        1:
    ]
    assert (missing["column"], missing["verdict"]) == ("DICP + plan", None)
    # rendered: the E table's header and row, and one verdict line per reading
    lines = render_report(both, cells, {"stages": [], "created": "now", "versions": {}}, tmp_path)
    lines = lines.splitlines()
    assert "| env | AD | DICP | DICP + plan |" in lines
    assert sum(line.startswith("| darkroom | +20.0 ± 1.0 (+25.1) |") for line in lines) == 1
    assert sum(line.startswith("- darkroom, ") for line in lines) == 3
    # the DICP model's departures from the reference code are said beside the paper's E
    (model,) = [line for line in lines if line.startswith("The DICP model is")]
    assert "coordinates states one-hot per coordinate (ours; the reference embeds" in model
    assert "beside the reference planner" in model
    cells = {**dicp, "train": {"by_objective": {"dicp": {"state_encoding": "cells"}}}}
    text = render_report(load_experiment(_spec(tmp_path, cells, "c")), [],
                         {"stages": [], "created": "now", "versions": {}}, tmp_path / "c")  # fmt: skip
    assert "states one-hot over the grid's cells (ours; the reference embeds context" in text
    # a table that does not plan has no cell for the paper's (planned) DICP E
    policy = {**dicp, "evaluate": {"plan_dicp": False}}
    exp = load_experiment(_spec(tmp_path, policy, "p"))
    text = render_report(exp, [], {"stages": [], "created": "now", "versions": {}}, tmp_path / "p")
    assert "this table does not plan, so the paper's DICP E" in text
    row = {"backbone": "DICP", "E": 0.1, "E_std": 0.01}
    (dicp_reading,) = [r for r in readings(exp, [{"env_id": "darkroom", "arm": "lhf",
                                                   "rows": [row]}]) if r["column"] == "DICP"]  # fmt: skip
    assert dicp_reading["paper"] is None


def test_a_custom_spec_s_report_names_it_by_its_path(tmp_path):
    """A shipped spec is named by its name, any other yaml by the path it was given as: the
    report's command line then runs as written (its stem would be an unknown experiment)."""
    from lhf_hf.reproduce.report import render_report

    path = _spec(tmp_path, TINY, "mine")
    custom = load_experiment(path, "quick")
    assert (custom.name, custom.spec) == ("mine", path)
    shipped = load_experiment("darkroom-main", "quick")
    assert shipped.spec == "darkroom-main"
    # a shipped spec given by its path is still the shipped one
    assert load_experiment(str(EXPERIMENTS_DIR / "darkroom-main.yaml"), "quick").spec == (
        "darkroom-main"
    )
    summary = {"stages": [], "created": "now", "versions": {}}
    text = render_report(custom, [], summary, Path("results/mine-quick"))
    assert f"`lhf reproduce {path} --preset quick --runs 2`" in text  # the default folder: no --out
    text = render_report(custom, [], summary, tmp_path / "elsewhere")
    assert f"`lhf reproduce {path} --preset quick --runs 2 --out {tmp_path / 'elsewhere'}`" in text
    # a path with a space is quoted, so the line still runs as written
    spaced = load_experiment(_spec(tmp_path, TINY, "my spec"), "quick")
    text = render_report(spaced, [], summary, Path("results/my spec-quick"))
    assert f"`lhf reproduce '{tmp_path / 'my spec.yaml'}' --preset quick --runs 2`" in text


def test_a_spec_named_like_a_shipped_one_has_no_default_folder(tmp_path, capsys, monkeypatch):
    """``mine/darkroom-main.yaml``'s default folder would be the shipped table's
    (``results/darkroom-main-quick``), whose report it would replace: it must name its own, and
    its report's command line always writes it."""
    from lhf_hf.configs.commands import ReproduceOptions
    from lhf_hf.reproduce.report import render_report
    from lhf_hf.reproduce.reproduce import estimate_experiment, import_command, report_out

    path = _spec(tmp_path, TINY, "darkroom-main")
    monkeypatch.chdir(tmp_path)  # the default folder would be results/... under the current one
    mine = load_experiment(path, "quick")
    assert (mine.name, mine.spec) == ("darkroom-main", path)
    with pytest.raises(ValueError, match="named like the shipped spec 'darkroom-main'.*--out"):
        report_out(mine)
    out = tmp_path / "r"
    assert main(["reproduce", path, "--work", str(tmp_path / "w"), "--estimate"]) == 0
    assert main(["reproduce", path, "--work", str(tmp_path / "w")]) == 1  # refused, nothing run
    assert not (tmp_path / "w").exists() and not Path("results/darkroom-main-quick").exists()
    capsys.readouterr()
    summary = {"stages": [], "created": "now", "versions": {}}
    for folder in (out, Path("results/darkroom-main-quick")):  # even the shipped one's name
        text = render_report(mine, [], summary, folder)
        assert f"`lhf reproduce {path} --preset quick --runs 2 --out {folder}`" in text
    assert report_out(load_experiment("darkroom-main", "quick")) == "results/darkroom-main-quick"
    # the estimate names the folder a run would write, or why a run would be refused one
    text = estimate_experiment(path, "quick", work=tmp_path / "w")
    assert "a run would be refused: " in text and "name this report's folder with --out" in text
    assert f"report in {out}" in estimate_experiment(path, "quick", work=tmp_path / "w", out=out)
    # the export's hint for finishing elsewhere: its --out, or a placeholder where it has none
    assert import_command(mine, 2, tmp_path / "e") == (
        f"lhf reproduce {path} --preset quick --runs 2 --out FOLDER --import-stages {tmp_path / 'e'}"
    )
    assert import_command(mine, None, "my e", "o d") == (
        f"lhf reproduce {path} --preset quick --out 'o d' --import-stages 'my e'"
    )
    shipped = load_experiment("darkroom-main", "cpu", objectives=["dicp"])
    assert import_command(shipped, None, "e") == (
        "lhf reproduce darkroom-main --preset cpu --objectives dicp --import-stages e"
    )
    # an empty --out would be the current folder
    with pytest.raises(ValueError, match="--out is empty"):
        ReproduceOptions(experiment="darkroom-main", out=" ")
    for flag in ("--out", "--export-stages"):
        assert main(["reproduce", "darkroom-main", flag, ""]) == 1
        assert f"{flag} is empty: name a folder" in capsys.readouterr().err


def test_planning_settings_reach_only_the_planned_evaluations(tmp_path):
    """``plan_dicp: both`` with ``plan_gate`` (a planning setting): the model-free evaluations are
    the same stages as without it (cached ones stay valid), the planned ones carry it."""
    dicp = {**TINY, "objectives": ["dicp"], "paper": {"darkroom": {"dicp": 15.2}}}
    plain = load_experiment(_spec(tmp_path, {**dicp, "evaluate": {"plan_dicp": "both"}}, "a"))
    gated = load_experiment(
        _spec(
            tmp_path, {**dicp, "evaluate": {"plan_dicp": "both", "plan_gate": "reward_seen"}}, "g"
        )
    )
    ev_a = plan_stages(plain, tmp_path)[1][("darkroom", "baseline", "dicp")]
    ev_g = plan_stages(gated, tmp_path)[1][("darkroom", "baseline", "dicp")]
    free = [(a.hash, g.hash) for a, g in zip(ev_a, ev_g, strict=True) if not a.config["plan"]]
    planned = [(a, g) for a, g in zip(ev_a, ev_g, strict=True) if a.config["plan"]]
    assert free and all(a == g for a, g in free)
    assert planned and all(a.hash != g.hash for a, g in planned)
    assert all(g.config["plan_gate"] == "reward_seen" for _, g in planned)
    assert gated.eval_config(0, model="m", out="o", plan="none").plan_gate == "always"


def test_dicp_is_evaluated_per_plan_mode_each_labelled(tmp_path):
    """plan_dicp [none, plan, gated]: three evaluation stages per DICP model; `plan` is the
    reference planner (no gate), `gated` its own row ("DICP + plan, gated"); the `both` alias keeps
    its stages' hashes; a spec gating every planned evaluation cannot also ask for `gated`."""
    dicp = {**TINY, "objectives": ["dicp"], "paper": {"darkroom": {"dicp": 15.2}}}
    three = load_experiment(
        _spec(tmp_path, {**dicp, "evaluate": {"plan_dicp": ["none", "plan", "gated"]}}, "t")
    )
    both = load_experiment(_spec(tmp_path, {**dicp, "evaluate": {"plan_dicp": "both"}}, "b"))
    ev_t = plan_stages(three, tmp_path)[1][("darkroom", "baseline", "dicp")]
    ev_b = plan_stages(both, tmp_path)[1][("darkroom", "baseline", "dicp")]
    assert len(ev_t) == 3 * three.runs and len(ev_b) == 2 * both.runs
    ev_t, ev_b = ev_t[:3], ev_b[:2]  # run 0's
    assert [(e.config["plan"], e.config["plan_gate"]) for e in ev_t] == [
        (False, "always"), (True, "always"), (True, "reward_seen")
    ]  # fmt: skip
    assert [e.hash for e in ev_t[:2]] == [e.hash for e in ev_b]
    assert [three.column("dicp", m) for m in ("none", "plan", "gated")] == [
        "DICP", "DICP + plan", "DICP + plan, gated"
    ]  # fmt: skip
    assert "DICP + plan, gated" in ev_t[2].label
    for bad, match in (
        ({"plan_dicp": ["plan", "plan"]}, "each once"),
        ({"plan_dicp": ["sometimes"]}, "a list of none, plan, gated"),
        ({"plan_dicp": ["plan", "gated"], "plan_gate": "reward_seen"}, "leave plan_gate out"),
        ({"plan_dicp": ["none:0.9"]}, "not a mode: 'none:0.9'$"),
        ({"plan_dicp": ["plan", "gated:1"]}, "not a mode: 'gated:1'$"),
        ({"plan_dicp": ["gated:high"]}, "plan:P or gated:P"),
        ({"plan_dicp": ["gated:0.99", "gated:0.990"]}, "given twice: 'gated:0.990'$"),
        ({"plan_dicp": ["gated:0.9"], "plan_reward_threshold": 0.5}, "leave it out"),
    ):
        with pytest.raises(UserError, match=match):
            load_experiment(_spec(tmp_path, {**dicp, "evaluate": bad}, "x"))


def test_plan_mode_with_a_reward_threshold(tmp_path):
    """``gated:0.99`` is the gated planner with the reward threshold 0.99: its own stage and row
    ("DICP + plan, gated, reward p >= 0.99"), beside the reference planner whose config (and so
    its stage hash) it leaves unchanged; ``plan:0.9`` thresholds without the gate."""
    dicp = {**TINY, "objectives": ["dicp"], "paper": {"darkroom": {"dicp": 15.2}}}
    modes = ["none", "plan", "gated", "gated:0.99", "plan:0.9"]
    five = load_experiment(_spec(tmp_path, {**dicp, "evaluate": {"plan_dicp": modes}}, "f"))
    three = load_experiment(_spec(tmp_path, {**dicp, "evaluate": {"plan_dicp": modes[:3]}}, "t"))
    ev_f = plan_stages(five, tmp_path)[1][("darkroom", "baseline", "dicp")][:5]
    ev_t = plan_stages(three, tmp_path)[1][("darkroom", "baseline", "dicp")][:3]
    assert [e.hash for e in ev_f[:3]] == [e.hash for e in ev_t]
    got = [(e.config["plan"], e.config["plan_gate"], e.config.get("plan_reward_threshold"))
           for e in ev_f]  # fmt: skip
    assert got == [
        (False, "always", None), (True, "always", None), (True, "reward_seen", None),
        (True, "reward_seen", 0.99), (True, "always", 0.9),
    ]  # fmt: skip
    assert [five.column("dicp", m) for m in modes[3:]] == [
        "DICP + plan, gated, reward p >= 0.99", "DICP + plan, reward p >= 0.9"
    ]  # fmt: skip
    assert "DICP + plan, gated, reward p >= 0.99" in ev_f[3].label
    assert five.eval_config(0, model="m", out="o", plan="none").plan_reward_threshold is None


def test_sweep_arms():
    exp = load_experiment("darkroom-lambda", "quick")
    arms = exp.filter_arms(2)
    assert [a for a, _ in arms] == ["lam=0", "lam=0.5", "lam=1", "lam=2", "lam=1000"]
    assert [f.lam for _, f in arms] == [0, 0.5, 1, 2, 1000]
    assert all(f.strategy == "linear" and f.seed == 2 for _, f in arms)
    assert load_experiment("darkroom-main", "quick").filter_arms(0) == [("lhf", FilterConfig())]


def test_the_verdict_is_the_paired_test_of_the_return_differences():
    # the demo's lightweight AD on noisy data (baseline 0.600 / 1.900 / 1.979, LHF 4.954 / 5.458 /
    # 4.696): per-run E 7.26 / 1.87 / 1.37, whose interval spans 0, while every difference is
    # +2.7 .. +4.4: the differences' interval decides
    diffs = np.array([4.954 - 0.600, 5.458 - 1.900, 4.696 - 1.979])
    half = 4.3027 * diffs.std(ddof=1) / np.sqrt(3)  # t(0.975, 2)
    d_ci = [diffs.mean() - half, diffs.mean() + half]
    assert d_ci[0] > 0
    assert verdict({"E": 2.37, "E_std": 2.66, "E_ci95": [-4.6, 11.6], "diff_ci95": d_ci}) == "helps"
    assert verdict({"E": -0.05, "E_ci95": [-0.16, 0.07], "diff_ci95": [-1.1, -0.2]}) == "hurts"
    assert (
        verdict({"E": 0.5, "E_ci95": [0.2, 0.8], "diff_ci95": [-0.3, 2.0]})
        == "no clear effect (the paired return difference's 95% CI spans 0)"
    )
    # a baseline returning 0 leaves E undefined, but not the difference, which then decides
    assert verdict({"E": None, "diff_ci95": [4.07, 6.0]}) == "helps"
    assert verdict({"E": None, "diff_ci95": None}).startswith("undefined")
    # one run: its sign, never a verdict (nor from a non-finite interval)
    assert verdict({"E": 0.03}) == (
        "not judged (1 paired run, no error bar): the return is higher with LHF"
    )
    assert verdict({"E": -0.03, "diff_ci95": [float("nan"), 1.0]}).endswith("lower with LHF")


@pytest.mark.slow
def test_reproduce_caches_stages_and_reports(tmp_path):
    spec = _spec(tmp_path, TINY)
    work, out = tmp_path / "work", tmp_path / "out"
    lines: list[str] = []
    report = reproduce(spec, "quick", out=out, work=work, echo=lines.append)
    summary = json.loads((out / "results.json").read_text())
    assert [s["cached"] for s in summary["stages"]] == [False] * 12  # 2 runs x 6 stages
    # run r: seed r and split r (different unseen tasks per run)
    evals = sorted(work.glob("evaluate/*/eval/eval_results.json"))
    results = [json.loads(p.read_text()) for p in evals]
    assert sorted(r["split_seed"] for r in results) == [0, 0, 1, 1]
    assert sorted(r["config"]["seed"] for r in results) == [0, 0, 1, 1]
    # E in the report = (LHF - baseline) / baseline of the whole-curve means, by hand
    cell = summary["cells"][0]["rows"][0]
    base = [r for r in results if r["model"]["selection"] is None]
    lhf = [r for r in results if r["model"]["selection"] is not None]
    mb = np.mean([np.mean(r["mean_curve"]) for r in base])
    mf = np.mean([np.mean(r["mean_curve"]) for r in lhf])
    if mb != 0:
        assert cell["E"] == pytest.approx((mf - mb) / mb)
    text = report.read_text()
    assert "(+25.1)" in text  # the paper's value beside ours
    assert (
        "darkroom/lhf/compare.png" in text and (out / "darkroom" / "lhf" / "compare.png").exists()
    )
    assert not (out / "darkroom" / "sweep.png").exists()  # one LHF arm: no sweep figure
    assert "## Where LHF helps" in text and "Budget" in text
    # what each run's selection kept: the source's mean return is the kept and rejected groups'
    # means weighted by their sizes
    sels = summary["selections"]
    assert [(s["env_id"], s["arm"], s["run"]) for s in sels] == [
        ("darkroom", "lhf", 0),
        ("darkroom", "lhf", 1),
    ]
    for s in sels:
        kept, rej = s["selected_unique"], s["rejected"]
        assert kept + rej == s["histories"] and kept > 0
        parts = kept * s["mean_return_selected_unique"] + rej * (s["mean_return_rejected"] or 0)
        assert parts == pytest.approx(s["histories"] * s["mean_return_source"])
    assert "## What LHF kept" in text and "| darkroom | lhf | 1 |" in text
    # A rerun is all cache hits and writes the same table.
    lines.clear()
    reproduce(spec, "quick", out=out, work=work, echo=lines.append)
    again = json.loads((out / "results.json").read_text())
    assert all(s["cached"] for s in again["stages"])
    assert again["cells"][0]["rows"] == summary["cells"][0]["rows"]
    # the table's cost: every stage's own recorded time, whichever call ran it
    recorded = sum(json.loads(p.read_text())["wall_s"] for p in work.glob("*/*/stage.json"))
    assert again["stage_s"] == summary["stage_s"] == pytest.approx(recorded, abs=0.1)
    assert recorded > 0
    assert "## Provenance" in report.read_text()
    assert sum("cached" in line for line in lines) == 12
    # Changing the training budget re-runs training and evaluation only.
    changed = json.loads(json.dumps(TINY))
    changed["presets"]["quick"]["train"]["max_steps"] = 6
    # every finished stage recorded what it cost, so the estimate times the 8 stages to re-run
    done = json.loads(next(work.glob("train/*/stage.json")).read_text())
    assert done["cost"]["units"] == 4 * 4 * 80 * 1  # steps x batch x context 80 x 1 token (AD)
    assert done["cost"]["key"] == "train|darkroom|ad|tiny|window" and done["cpu"]
    text = estimate_experiment(_spec(tmp_path, changed), "quick", work=work)
    assert "8 of 12 stage(s) to run" in text and "no measured rate" not in text
    assert text.count("cached") == 4 and text.count("(here, ") == 8
    assert main(["reproduce", _spec(tmp_path, changed), "--work", str(work), "--estimate"]) == 0
    reproduce(_spec(tmp_path, changed), "quick", out=out, work=work, echo=lines.append)
    third = json.loads((out / "results.json").read_text())
    kind = {True: set(), False: set()}
    for st in third["stages"]:
        kind[st["cached"]].add(Path(st["path"]).parent.name)
    assert kind == {True: {"collect", "filter"}, False: {"train", "evaluate"}}
    assert sum(not st["cached"] for st in third["stages"]) == 8  # 2 runs x 2 models x (train, eval)


def test_cli_errors(capsys):
    assert main(["reproduce", "no-such-experiment"]) == 1
    assert "unknown experiment 'no-such-experiment'" in capsys.readouterr().err


@pytest.mark.slow
def test_half_histories_and_sweep_arms(tmp_path):
    from lhf_hf.histories import load_histories

    spec = json.loads(json.dumps(TINY))
    spec["collect"] = {"half": True}
    spec["filter"] = {"strategy": "linear", "sweep": {"key": "lam", "values": [0, 1000]}}
    spec["presets"]["quick"]["runs"] = 1
    work, out = tmp_path / "work", tmp_path / "out"
    report = reproduce(
        _spec(tmp_path, spec, "half"), "quick", out=out, work=work, echo=lambda s: None
    )
    summary = json.loads((out / "results.json").read_text())
    kinds = [Path(s["path"]).parent.name for s in summary["stages"]]
    assert kinds == ["collect", "derive", "filter", "filter"] + ["train", "evaluate"] * 3
    full = load_histories(next(work.glob("collect/*")) / "data")
    half = load_histories(next(work.glob("derive/*")) / "data")
    assert half.info["total_frames"] * 2 == full.info["total_frames"]  # 200 -> 100 transitions
    # both LHF arms were filtered from the half dataset, with their own lambda
    for sel in work.glob("filter/*/selection/filter_config.json"):
        meta = json.loads(sel.read_text())
        assert meta["source"]["fingerprint"] == half.fingerprint
    assert sorted(c["arm"] for c in summary["cells"]) == ["lam=0", "lam=1000"]
    text = report.read_text()
    assert "| darkroom (lam=0) |" in text and "| darkroom (lam=1000) |" in text
    # the sweep's figure: every value on one panel per backbone, linked first in the report
    assert (out / "darkroom" / "sweep.png").stat().st_size > 0
    assert text.index("(darkroom/sweep.png)") < text.index("(darkroom/lam=0/compare.png)")


def test_objectives_narrow_the_grid_to_stages_of_the_full_table(tmp_path, capsys):
    """``objectives``: only those backbones' stages, with the same hashes as in the full plan (a
    later full run finds them cached), the report named after them; an unknown one fails early."""
    from lhf_hf.reproduce.reproduce import plan_stages, report_out

    full = load_experiment("darkroom-main", "cpu", 3)
    dicp = load_experiment("darkroom-main", "cpu", 3, objectives=["dicp"])
    assert dicp.objectives == ("dicp",) and dicp.narrowed and not full.narrowed
    assert load_experiment("darkroom-main", "cpu", 3, ["dpt", "ad", "dicp"]) == full  # all = full
    assert load_experiment("darkroom-main", "cpu", 3, ["dpt", "ad"]).objectives == ("ad", "dpt")
    work = tmp_path / "w"
    all_stages = {s.hash: s for s in plan_stages(full, work)[0]}
    some = plan_stages(dicp, work)[0]
    assert {s.hash for s in some} <= set(all_stages)
    trained = [s.config["objective"] for s in some if s.kind == "train"]
    assert trained == ["dicp"] * 6  # 3 runs x (baseline, LHF)
    assert sum(s.kind == "evaluate" for s in some) == 12  # none, plan
    assert report_out(dicp) == "results/darkroom-main-cpu-dicp"
    assert report_out(full) == "results/darkroom-main-cpu"
    with pytest.raises(ValueError, match="darkroom-main has no backbone 'bc': choose among"):
        load_experiment("darkroom-main", "cpu", objectives=["bc"])
    # the quick preset narrows the spec to AD: the error names what this preset has
    assert main(["reproduce", "darkroom-noisy", "--objectives", "dicp", "--estimate"]) == 1
    assert "darkroom-noisy has no backbone 'dicp': choose among ['ad']" in capsys.readouterr().err
    assert main(["reproduce", "darkroom-noisy", "--preset", "cpu", "--objectives", "dicp",
                 "--work", str(work), "--estimate"]) == 0  # fmt: skip
    assert "1 backbone(s), 24 stages" in capsys.readouterr().out  # 3 x (collect, filter, 2 + 4)


@pytest.mark.slow
def test_a_train_stage_resumes_a_whole_checkpoint_or_starts_clean(tmp_path, monkeypatch):
    """A training stage's model folder left by a killed run: without a checkpoint it is removed
    before training (an --overwrite would set it aside and, interrupted, put it back over the new
    checkpoints); with one, the newest complete checkpoint is resumed (a save cut short is not)."""
    import importlib

    from lhf_hf.reproduce.stages import DONE_FILE, StageRunner

    reproduce_module = importlib.import_module("lhf_hf.reproduce.reproduce")  # not the function

    spec = json.loads(json.dumps(TINY))
    spec["presets"]["quick"].update(runs=1)
    spec["presets"]["quick"]["train"].update(save_steps=2)
    exp = load_experiment(_spec(tmp_path, spec), "quick")
    work = tmp_path / "work"
    stages, _ = plan_stages(exp, work)
    runner = StageRunner(work, echo=lambda s: None)
    stage = next(s for s in stages if s.kind == "train")
    for s in stages[: stages.index(stage)]:  # its collection and selection
        runner.run(s)
    model = stage.path(work) / "model"
    model.mkdir(parents=True)
    (model / ".lhf_output.json").write_text('{"kind": "model", "lhf_hf": "0.1.0"}')
    (model / "train_config.json").write_text("{")  # killed before its first checkpoint
    seen = []
    real_train = reproduce_module.train

    def train(cfg, **kw):
        seen.append((model.exists(), cfg.resume, cfg.overwrite))
        return real_train(cfg, **kw)

    monkeypatch.setattr(reproduce_module, "train", train)
    runner.run(stage)
    assert seen == [(False, False, True)] and stage.done(work)
    assert not list(model.parent.glob(".model.replaced-*"))
    assert json.loads((model / "train_config.json").read_text())["resumed_from"] is None
    # killed again during the save of checkpoint-4: checkpoint-2 is resumed
    (stage.path(work) / DONE_FILE).unlink()
    (model / "checkpoint-4" / "trainer_state.json").unlink()
    runner.run(stage)
    assert seen[1] == (True, True, False) and stage.done(work)
    resumed = json.loads((model / "train_config.json").read_text())["resumed_from"]
    assert resumed.endswith("checkpoint-2")


def test_the_collect_stage_is_named_by_the_resolved_ppo_backend(tmp_path, monkeypatch):
    """With ppo_backend `auto`, which backend runs depends on a timing on this machine, and the
    kernel and torch ops draw different random numbers: the stage hash names the resolved backend,
    so one stage name never stands for two datasets."""
    import importlib

    rep = importlib.import_module("lhf_hf.reproduce.reproduce")  # the module, not the function
    exp = load_experiment(_spec(tmp_path, TINY), "quick")
    hashes = {}
    for backend in ("kernel", "torch"):
        monkeypatch.setattr(rep, "resolve_ppo_backend", lambda cfg, b=backend: b)
        stages, _ = plan_stages(exp, tmp_path)
        collect = [s for s in stages if s.kind == "collect"]
        assert all(s.config.get("ppo_backend", "torch") == backend for s in collect)
        hashes[backend] = {s.hash for s in collect}
    assert not hashes["kernel"] & hashes["torch"]


def test_the_train_stage_is_named_by_the_attention_code_that_trains(tmp_path, monkeypatch):
    """With attention_kernel `auto`, the C++ kernel trains where it builds and the torch path
    elsewhere, and their dropout masks differ: the stage hash names the one planned (the torch
    path keeps the hash of stages from before the field), and the training runs with it."""
    import importlib

    from lhf_hf.modeling import attention_kernel
    from lhf_hf.training.attention_backend import planned_attention_kernel

    rep = importlib.import_module("lhf_hf.reproduce.reproduce")  # the module, not the function
    exp = load_experiment(_spec(tmp_path, TINY), "quick")
    hashes = {}
    for why_not in (None, "no compiler"):
        monkeypatch.setattr(attention_kernel, "available", lambda w=why_not: w)
        stages, _ = plan_stages(exp, tmp_path)
        train = [s for s in stages if s.kind == "train"]
        want = "kernel" if why_not is None else "torch"
        assert all(s.config.get("attention_kernel", "torch") == want for s in train)
        assert ("attention_kernel" in train[0].config) == (want == "kernel")
        hashes[want] = {s.hash for s in train}
    assert not hashes["kernel"] & hashes["torch"]
    # what the stage's training is given: the planned code, never `auto`
    ran = []
    monkeypatch.setattr(rep, "train", lambda cfg, progress=True: ran.append(cfg.attention_kernel))
    monkeypatch.setattr(attention_kernel, "available", lambda: None)
    stages, _ = plan_stages(exp, tmp_path)
    next(s for s in stages if s.kind == "train").fn(tmp_path / "stage")
    assert ran == ["kernel"]
    # settings the kernel leaves to torch are planned as torch (tiny's head dim 8 is the kernel's)
    cfg = exp.train_config("ad", 0, dataset="", selection=None, out="")
    assert planned_attention_kernel(cfg) == "kernel"
    assert (
        planned_attention_kernel(dataclasses.replace(cfg, training_args={"bf16": "true"}))
        == "torch"
    )
    assert planned_attention_kernel(dataclasses.replace(cfg, attention_kernel="torch")) == "torch"


def test_a_spec_says_how_each_named_setting_was_chosen(tmp_path):
    """``choices`` names settings the spec sets, each with how it was chosen and the evidence;
    the report's table shows them with their values.  A choice of a setting the spec does not
    set, an unknown kind or no evidence is refused at load, and so is a preset whose choices
    leave out a setting it sets."""
    from lhf_hf.reproduce.report import _choices

    spec = json.loads(json.dumps(TINY))
    rest = ("collect.steps", "collect.tasks", "evaluate.episodes", "train.batch_size",
            "train.preset", "train.save_steps")  # fmt: skip
    spec["presets"]["quick"]["choices"] = {
        "train.max_steps": {"chosen": "budget", "evidence": "what 2 cores afford"},
        "collect.histories": {"chosen": "validation", "evidence": "results/x.md"},
        "runs": {"chosen": "budget", "evidence": "t quantiles"},
        **{k: {"chosen": "design", "evidence": "a tiny test"} for k in rest},
    }
    exp = load_experiment(_spec(tmp_path, spec), "quick")
    assert exp.setting("train.max_steps") == 4 and exp.setting("collect.histories") == 4
    rows = [line for line in _choices(exp) if line.startswith("| `")]
    assert len(rows) == 9 and {"| `collect.histories` | `4` | validation | results/x.md |",
                               "| `runs` | `2` | budget | t quantiles |",
                               "| `train.max_steps` | `4` | budget | what 2 cores afford |"} <= set(rows)  # fmt: skip
    # every setting the preset sets, or none: a list a reviewer reads as complete
    incomplete = json.loads(json.dumps(spec))
    del incomplete["presets"]["quick"]["choices"]["train.batch_size"]
    del incomplete["presets"]["quick"]["choices"]["runs"]
    with pytest.raises(
        ValueError, match="every setting the preset sets; none for runs, train.batch_size$"
    ):
        load_experiment(_spec(tmp_path, incomplete, "incomplete"), "quick")
    assert _choices(load_experiment(_spec(tmp_path, TINY, "none"), "quick")) == []
    # --runs another count: the spec's reason for its count no longer applies; a pipe is escaped
    spec["presets"]["quick"]["choices"]["collect.histories"]["evidence"] = "a | b"
    path = _spec(tmp_path, spec, "piped")
    assert "runs" in load_experiment(path, "quick", runs=2).choices
    assert "runs" not in load_experiment(path, "quick", runs=5).choices
    assert "| `collect.histories` | `4` | validation | a \\| b |" in _choices(
        load_experiment(path, "quick")
    )
    for choice, message in [
        ({"train.lr": {"chosen": "budget", "evidence": "x"}}, "the spec sets no 'train.lr'"),
        ({"train": {"chosen": "budget", "evidence": "x"}}, "name a setting"),
        ({"model.x": {"chosen": "budget", "evidence": "x"}}, "the spec sets no 'model.x'"),
        ({"train.max_steps": {"chosen": "luck", "evidence": "x"}}, "chosen must be one of"),
        ({"train.max_steps": {"chosen": "budget", "evidence": " "}}, "evidence must be a text"),
        ({"train.max_steps": {"chosen": "budget", "evidence": 42}}, "got 42"),
        ({"train.max_steps": "budget"}, r"must be \{chosen: ..., evidence: ...\}"),
        (["train.max_steps"], "choices must map settings .* got a list"),
    ]:
        bad = json.loads(json.dumps(spec))
        whole = bad["presets"]["quick"]["choices"]
        bad["presets"]["quick"]["choices"] = (
            {**whole, **choice} if isinstance(choice, dict) else choice
        )
        with pytest.raises(ValueError, match=message):
            load_experiment(_spec(tmp_path, bad, "bad"), "quick")


def test_the_shipped_main_and_noisy_tables_say_how_their_settings_were_chosen():
    for name in ("darkroom-main", "darkroom-noisy", "darkroom-main-learners"):
        exp = load_experiment(name, "cpu")
        chosen = {k: c["chosen"] for k, c in exp.choices.items()}
        # first set on test goals; the validation goals show one rollout is too few, not that 4
        # beats 8, and do not tell the learning rates apart
        assert chosen["evaluate.rollouts"] == chosen["train.lr"] == "test"
        assert chosen["runs"] == "paper" and exp.runs == 3
        if name == "darkroom-main-learners":
            continue  # AD and DPT only
        # first fixed on test goals; the validation goals do not decide it (one seed per length)
        assert chosen["train.by_objective.dicp.max_steps"] == "test"
        assert exp.setting("train.by_objective.dicp.max_steps") == 4000
        # our planner variants did not survive the validation goals: the reference planner only
        assert exp.dicp_plan_modes() == ("none", "plan")
        assert chosen["evaluate.plan_dicp"] == "validation"
        assert chosen["train.by_objective.dicp.reward_weighting"] == "reference"
        # narrowed to AD and DPT: DICP's choices describe no cell of that table
        narrowed = load_experiment(name, "cpu", objectives=["ad", "dpt"]).choices
        assert "evaluate.rollouts" in narrowed and not [k for k in narrowed if "dicp" in k]


def test_every_shipped_cpu_preset_says_how_each_of_its_settings_was_chosen():
    """A reported table's reader finds a label for every setting its preset sets (the loader then
    checks the list is complete), and a test-goal choice is labelled ``test``, never left out."""
    for name in experiment_names():
        exp = load_experiment(name, "cpu")
        assert exp.choices, f"{name}: its cpu preset has no choices"
        assert "runs" in exp.choices, name
        # the learning rate was first picked on test goals wherever it is set
        if "lr" in exp.train:
            assert exp.choices["train.lr"]["chosen"] == "test", name
