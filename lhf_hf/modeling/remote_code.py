"""The model's code beside its weights, so that transformers alone loads a checkpoint:
``AutoModel.from_pretrained(path, trust_remote_code=True)`` in an environment without lhf_hf
(docs/hub.md, "Loading a model with transformers alone").

transformers' own route (``register_for_auto_class``: ``save_pretrained`` then copies the file that
defines the class and the files it imports relatively, ``custom_object_save``) copies files
verbatim, and ours import three lhf_hf modules: the error type (``lhf_hf.errors``), the model field
rules that ``TrainConfig`` shares (``lhf_hf.configs.model``) and the objective names
(``lhf_hf.constants``).  Those rules sit in ``lhf_hf.configs`` so that the CLI checks its flags
without importing transformers (docs/design.md 1, layers); moving them into the modeling files would
make every flag check pay for transformers, and a second copy would be a second version of one
rule.  So a checkpoint gets a bundle made at save time from the package's own files:

- the four modeling files (``configuration_icrl.py``, ``modeling_icrl.py``, ``attention.py``,
  ``train_attention.py``) under their own names, so their relative imports of each other hold;
- the three lhf_hf modules they import, one file each (``configs_model.py``, ``constants.py``,
  ``errors.py``);
- in every file, each ``from lhf_hf.X import`` line turned into ``from .<X's file> import``: the
  only change, besides a first comment line naming the source file.

The package stays the one source of truth; tests check that the bundle imports nothing of lhf_hf and
computes what the package computes (``tests/modeling/test_remote_code.py``, and in a venv without
lhf_hf ``tests/modeling/test_transformers_only.py``).

Why not a ``save_pretrained`` override on the model: the model file is itself in the bundle, and a
bundled file cannot reach the package's sources.  ``lhf train`` calls ``save_model_code`` before
every save (``WindowTrainer._save``) and ``lhf push`` adds the bundle to a checkpoint saved before
it existed.  A model saved by hand with ``model.save_pretrained`` gets no code unless
``save_model_code`` is called first.
"""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

from lhf_hf import __version__
from lhf_hf.utils.io import write_text_atomic

#: Package module -> its file beside the weights.  The ``lhf_hf.modeling`` files keep their names.
MODEL_CODE: dict[str, str] = {
    "lhf_hf.modeling.configuration_icrl": "configuration_icrl.py",
    "lhf_hf.modeling.modeling_icrl": "modeling_icrl.py",
    "lhf_hf.modeling.attention": "attention.py",
    "lhf_hf.modeling.train_attention": "train_attention.py",
    "lhf_hf.configs.model": "configs_model.py",
    "lhf_hf.constants": "constants.py",
    "lhf_hf.errors": "errors.py",
}
#: The files of the bundle, as a checkpoint holds them.
MODEL_CODE_FILES: tuple[str, ...] = tuple(sorted(MODEL_CODE.values()))
#: ``config.json``'s ``auto_map``: which class of which file each Auto class loads.
AUTO_MAP: dict[str, str] = {
    "AutoConfig": "configuration_icrl.ICRLConfig",
    "AutoModel": "modeling_icrl.ICRLModel",
}

_LHF_IMPORT = re.compile(r"^from (lhf_hf\.[\w.]+) import ", re.MULTILINE)


def model_code() -> dict[str, str]:
    """The bundle: file name -> source text (the package's file, imports pointed at the bundle)."""
    return {name: _bundled(module, name) for module, name in MODEL_CODE.items()}


def _bundled(module: str, name: str) -> str:
    relative = Path(*module.split(".")).with_suffix(".py").as_posix()  # lhf_hf/configs/model.py

    def point(m: re.Match) -> str:
        target = MODEL_CODE.get(m[1])
        if target is None:  # a bug of ours: tests/modeling/test_remote_code.py checks the bundle
            raise RuntimeError(f"{relative} imports {m[1]}, which is not in MODEL_CODE")
        return f"from .{target.removesuffix('.py')} import "

    source = Path(importlib.import_module(module).__file__).read_text(encoding="utf-8")
    text = _LHF_IMPORT.sub(point, source)
    for node in ast.walk(ast.parse(text)):  # what the line rewrite does not cover: `import lhf_hf`
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names = [node.module or ""]
        else:
            continue
        if any(n.split(".")[0] == "lhf_hf" for n in names):
            raise RuntimeError(
                f"{relative} line {node.lineno}: an lhf_hf import outside MODEL_CODE"
            )
    header = f"# lhf_hf {__version__}: {relative}, saved beside the weights (lhf_hf.modeling.remote_code)"
    return f"{header}\n{text}"


def save_model_code(folder: str | Path, config=None) -> list[Path]:
    """Write the bundle into ``folder``; with ``config``, set its ``auto_map`` (call before
    ``save_pretrained``, which writes it into ``config.json``).  Returns the files written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in model_code().items():
        write_text_atomic(text, folder / name)
        written.append(folder / name)
    if config is not None:
        config.auto_map = dict(AUTO_MAP)
    return written


def with_auto_map(config_json: dict) -> dict:
    """A ``config.json`` dict with ``auto_map`` naming the bundle (a checkpoint saved before it)."""
    return {**config_json, "auto_map": {**(config_json.get("auto_map") or {}), **AUTO_MAP}}
