"""Tests of scripts/ (not a package: each script is loaded by its path)."""

import importlib.util
import sys
from pathlib import Path

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


def load_script(name: str):
    """``scripts/NAME.py`` as the module ``NAME`` (its sibling imports, ``results_coverage``,
    resolve as they do when the script runs from its folder)."""
    if name not in sys.modules:
        if name == "results_index":
            load_script("results_coverage")
        spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]
