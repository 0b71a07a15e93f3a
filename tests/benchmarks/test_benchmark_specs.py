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


def test_the_key_to_door_planning_spec_is_a_cell_of_the_planning_spec(tmp_path):
    # the same stages (hashes): a later run of planning.yaml finds them cached
    one = plan_stages(
        load_experiment(str(ROOT / "calibration" / "planning-key-to-door.yaml"), "cpu"), tmp_path
    )[0]
    all_ = plan_stages(
        load_experiment(str(ROOT / "calibration" / "planning.yaml"), "cpu"), tmp_path
    )[0]
    k2d = [s.hash for s in all_ if s.label.startswith("dark-key-to-door")]
    assert [s.hash for s in one] == k2d and len(k2d) == 6
