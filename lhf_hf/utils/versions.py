"""The library versions every artifact records (dataset, selection, checkpoint, eval result)."""

from __future__ import annotations

import platform
from collections.abc import Iterable
from importlib.metadata import PackageNotFoundError, version


def library_versions(extra: Iterable[str] = ()) -> dict[str, str]:
    """Versions of the libraries that shape the data (recorded in every artifact)."""
    names = [
        "lhf_hf",
        "numpy",
        "pyarrow",
        "datasets",
        "huggingface-hub",
        "gymnasium",
        "stable-baselines3",
        "torch",
        *extra,
    ]
    out = {"python": platform.python_version()}
    for name in names:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            pass
    return out
