"""The model code a checkpoint carries (``lhf_hf.modeling.remote_code``): the package's own files,
importing nothing of lhf_hf, computing what the package computes.  The same in a venv without
lhf_hf, through transformers' ``trust_remote_code``: ``test_transformers_only.py`` (slow tier)."""

from __future__ import annotations

import ast
import importlib
import json
import re
import sys
from pathlib import Path

import pytest
import torch
from transformers import AttentionInterface, AutoConfig, AutoModel
from transformers.masking_utils import ALL_MASK_ATTENTION_FUNCTIONS, sdpa_mask

from lhf_hf.modeling import ICRLConfig, ICRLModel, icrl_config, load_model, save_model_code
from lhf_hf.modeling import train_attention as package_attention
from lhf_hf.modeling.remote_code import AUTO_MAP, MODEL_CODE, MODEL_CODE_FILES, model_code

#: What a bundled file may import besides the bundle: transformers and what it depends on.
ALLOWED = {"torch", "transformers", "huggingface_hub", "numpy"}


def _imports(text: str):
    """(top-level module or None, relative module or None) of every import in ``text``."""
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name.split(".")[0], None
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                assert node.level == 1 and node.module, ast.unparse(node)  # `from .x import`
                yield None, node.module
            else:
                yield node.module.split(".")[0], None


def test_the_bundle_imports_only_torch_transformers_the_stdlib_and_itself():
    code = model_code()
    assert sorted(code) == list(MODEL_CODE_FILES)
    for name, text in code.items():
        for top, relative in _imports(text):
            if relative is not None:  # transformers copies `from .x import` targets beside it
                assert f"{relative}.py" in code, f"{name} imports .{relative}, not in the bundle"
            else:
                assert top in ALLOWED or top in sys.stdlib_module_names, f"{name} imports {top}"
    for ref in AUTO_MAP.values():
        module, cls = ref.split(".")
        assert f"class {cls}(" in code[f"{module}.py"]


def test_each_bundled_file_is_the_package_file_with_its_lhf_hf_imports_pointed_beside_it():
    """One source of truth: a bundled file differs from the package's only in its first comment
    line and in its ``from lhf_hf.X import`` lines."""
    code = model_code()
    for module, name in MODEL_CODE.items():
        ours = Path(importlib.import_module(module).__file__).read_text().splitlines()
        header, *bundled = code[name].splitlines()
        assert header.startswith("# lhf_hf ") and Path(*module.split(".")).as_posix() in header
        assert len(bundled) == len(ours)
        for a, b in zip(ours, bundled, strict=True):
            if a != b:
                m = re.match(r"from (lhf_hf\.[\w.]+) import (.*)", a)
                assert m, f"{name}: {a!r} -> {b!r}"
                assert b == f"from .{MODEL_CODE[m[1]].removesuffix('.py')} import {m[2]}"


@pytest.fixture
def import_bundle(tmp_path, monkeypatch):
    """Imports the bundle as a package of its own (as transformers imports it); puts the attention
    function it registers back to the package's afterwards."""
    package = tmp_path / "icrl_bundle_test"
    package.mkdir()
    (package / "__init__.py").write_text("")
    save_model_code(package)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield lambda: importlib.import_module("icrl_bundle_test.modeling_icrl")
    for name in [m for m in sys.modules if m.startswith("icrl_bundle_test")]:
        del sys.modules[name]
    AttentionInterface.register(package_attention.NAME, package_attention.attention_forward)
    ALL_MASK_ATTENTION_FUNCTIONS.register(package_attention.NAME, sdpa_mask)


def _inputs(config, B=2, T=12, seed=0) -> dict[str, torch.Tensor]:
    """A DICP window of integer states, with labels (so the losses are compared too)."""
    g = torch.Generator().manual_seed(seed)
    S, bins, A = config.state_dim, config.state_bins, config.action_dim

    def ints(high, *shape):
        return torch.randint(0, high, shape, generator=g)

    return dict(
        states=ints(bins, B, T, S),
        prev_states=ints(bins, B, T, S),
        prev_actions=ints(A, B, T),
        prev_rewards=ints(2, B, T).float(),
        prev_dones=torch.zeros(B, T),
        has_prev=torch.ones(B, T, dtype=torch.bool),
        actions=ints(A, B, T),
        action_labels=ints(A, B, T),
        reward_labels=ints(2, B, T).float(),
        next_state_labels=ints(bins, B, T, S),
        return_labels=torch.rand(B, T, generator=g),
    )


def test_the_bundle_computes_what_the_package_computes(import_bundle):
    """Outputs and losses, in eval mode and in training mode (dropout, the training attention of
    ``train_attention.py``, drawn from the same seed), with band attention over more transitions
    than the context (``attention.py``'s mask)."""
    config = icrl_config("tiny", objective="dicp", env_id="darkroom", state_bins=9,
                         reward_values=[0.0, 1.0], context_length=4, attention="band",
                         attention_dropout=0.1, embedding_dropout=0.1)  # fmt: skip
    x = _inputs(config)
    ours = ICRLModel(config)
    expected = {}
    for mode in (False, True):  # before the bundle registers its own copy of the attention
        torch.manual_seed(0)
        with torch.no_grad():
            expected[mode] = ours.train(mode)(**x)
    bundle = import_bundle()
    theirs = bundle.ICRLModel(bundle.ICRLConfig.from_dict(config.to_dict()))
    theirs.load_state_dict(ours.state_dict())
    assert type(theirs).__module__ == "icrl_bundle_test.modeling_icrl"
    for mode in (False, True):
        torch.manual_seed(0)
        with torch.no_grad():
            got = theirs.train(mode)(**x)
        keys = [k for k, v in expected[mode].items() if isinstance(v, torch.Tensor)]
        assert {"loss", "action_logits", "reward_logits", "next_state_logits"} <= set(keys)
        for k in keys:
            assert torch.equal(expected[mode][k], got[k]), (mode, k)
    assert not torch.equal(expected[False]["loss"], expected[True]["loss"])  # dropout did act
    # its config checks its fields as the package's does, with its own copy of the error type
    with pytest.raises(ValueError, match=r"ICRLConfig.state_bins must be 0"):
        bundle.ICRLConfig(state_bins=1)


def test_load_model_reads_a_checkpoint_saved_before_checkpoints_carried_code(tmp_path):
    """No auto_map, no .py files (what `save_pretrained` alone writes): loads as before."""
    model = ICRLModel(icrl_config("tiny", objective="ad", env_id="darkroom", state_bins=9))
    model.save_pretrained(tmp_path / "old")
    assert "auto_map" not in json.loads((tmp_path / "old" / "config.json").read_text())
    assert not list((tmp_path / "old").glob("*.py"))
    loaded = load_model(str(tmp_path / "old"))
    assert type(loaded) is ICRLModel
    assert all(torch.equal(loaded.state_dict()[k], v) for k, v in model.state_dict().items())


def test_with_lhf_hf_imported_a_checkpoints_code_never_runs(tmp_path):
    """load_model, and the Auto classes even with trust_remote_code=True, build lhf_hf's own
    registered classes (import lhf_hf.modeling registers them; transformers prefers them)."""
    model = ICRLModel(icrl_config("tiny", objective="ad", env_id="darkroom", state_bins=9))
    save_model_code(tmp_path / "m", model.config)
    model.save_pretrained(tmp_path / "m")
    assert json.loads((tmp_path / "m" / "config.json").read_text())["auto_map"] == AUTO_MAP
    for name in ("configuration_icrl.py", "modeling_icrl.py"):
        (tmp_path / "m" / name).write_text("raise RuntimeError('the checkpoint code ran')\n")
    assert type(load_model(str(tmp_path / "m"))) is ICRLModel
    assert type(AutoConfig.from_pretrained(tmp_path / "m", trust_remote_code=True)) is ICRLConfig
    assert type(AutoModel.from_pretrained(tmp_path / "m", trust_remote_code=True)) is ICRLModel
