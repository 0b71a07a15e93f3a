"""``lhf_hf.collection`` imports its collectors on first use: the batched PPO needs torch alone."""

import subprocess
import sys

import pytest


def _fresh_python(code: str) -> str:
    """What ``code`` prints in a fresh interpreter (nothing imported before it)."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return out.stdout.strip()


@pytest.mark.slow
def test_batched_ppo_imports_without_sb3_or_datasets():
    code = (
        "import sys; import lhf_hf.collection.ppo_backends; "
        "heavy = [m for m in ('stable_baselines3', 'datasets', 'gymnasium') if m in sys.modules]; "
        "print(heavy)"
    )
    assert _fresh_python(code) == "[]"


def test_lazy_exports_are_the_functions():
    import lhf_hf.collection as col
    from lhf_hf.collection import collect

    assert callable(collect) and collect.__module__ == "lhf_hf.collection.driver"
    assert col.collect is collect  # not the same-named submodule
    assert callable(col.plan_task) and callable(col.collect_task_histories)
    assert col.RecordingVecEnv.__name__ == "RecordingVecEnv"
    with pytest.raises(AttributeError, match="nothing_here"):
        col.nothing_here  # noqa: B018


@pytest.mark.slow
def test_exports_stay_the_functions_when_their_modules_are_imported_first():
    """Importing an export's defining module on its own first (to patch it, say) must not turn the
    package attribute into a module: with ``collect`` defined in ``collection/collect.py`` the CLI
    then failed with "'module' object is not callable"."""
    code = (
        "import importlib, types, lhf_hf.collection as col; "
        "[importlib.import_module(m, col.__name__) for m in col._EXPORTS.values()]; "
        "print(sorted(n for n in col._EXPORTS if isinstance(getattr(col, n), types.ModuleType)))"
    )
    assert _fresh_python(code) == "[]"
