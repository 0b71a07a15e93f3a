"""The experiment specs under benchmarks/ (calibration, GPU) load as the experiments they describe."""

from pathlib import Path

import pytest

from lhf_hf.reproduce.experiment import load_experiment
from lhf_hf.reproduce.reproduce import plan_stages

ROOT = Path(__file__).resolve().parents[2] / "benchmarks"
SPECS = sorted([*ROOT.glob("calibration/*.yaml"), *ROOT.glob("gpu/*.yaml")])


@pytest.mark.parametrize("spec", SPECS, ids=[p.name for p in SPECS])
def test_each_benchmark_spec_plans(spec, tmp_path):
    import yaml

    presets = yaml.safe_load(spec.read_text())["presets"]
    for preset in presets:
        stages, _ = plan_stages(load_experiment(str(spec), preset), tmp_path)
        assert stages and {s.kind for s in stages} >= {"collect", "train", "evaluate"}


def test_the_gpu_dicp_spec_is_the_cpu_recipe_trained_three_times_longer(tmp_path):
    long = load_experiment(str(ROOT / "gpu" / "darkroom-main-dicp-long.yaml"), "cpu")
    cpu = load_experiment("darkroom-main", "cpu", objectives=["dicp"])
    (t_long,) = [s.config for s in plan_stages(long, tmp_path)[0] if s.kind == "train"][:1]
    (t_cpu,) = [s.config for s in plan_stages(cpu, tmp_path)[0] if s.kind == "train"][:1]
    assert (t_long["max_steps"], t_cpu["max_steps"]) == (12000, 4000)
    # the rest of the recipe is the cpu preset's: same data, model, batch, learning rate
    assert {**t_long, "max_steps": 0} == {**t_cpu, "max_steps": 0}
    assert long.runs == 2 and long.objectives == cpu.objectives


def test_the_planning_specs_evaluate_the_checkpoints_of_the_gridworlds_spec(tmp_path):
    # the same collection, filter and training stages (hashes): a run of gridworlds.yaml leaves
    # the planning specs only their planned evaluations; Key-to-Door's (~40 min) has its own spec
    def plan(name):
        return plan_stages(load_experiment(str(ROOT / "calibration" / name), "cpu"), tmp_path)[0]

    grid = {s.hash for s in plan("gridworlds.yaml")}
    for name, envs in [("planning.yaml", 3), ("planning-key-to-door.yaml", 1)]:
        stages = plan(name)
        upstream = [s for s in stages if s.kind != "evaluate"]
        assert upstream and {s.hash for s in upstream} <= grid
        planned = [s for s in stages if s.kind == "evaluate"]
        assert len(planned) == 2 * envs  # baseline and LHF arm per env
    k2d = [s for s in plan("planning.yaml") if s.label.startswith("dark-key-to-door")]
    assert not k2d
