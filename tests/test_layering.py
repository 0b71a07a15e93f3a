"""The package's layering (docs/design.md 1): a module imports only from lower layers (or its own package),
and no function-level import of lhf_hf is needed to break a cycle: the few that remain carry a
``# deferred: <reason>`` comment (a heavy or optional dependency)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "lhf_hf"

#: lowest first; a module may import from a lower layer or from its own subpackage
LAYERS = [
    ["lhf_hf", "lhf_hf.constants", "lhf_hf.errors"],  # column and file names, the UserError type
    ["lhf_hf.utils"],  # atomic io, versions, Hub access, templates, C++ kernel builds
    ["lhf_hf.envs"],
    ["lhf_hf.configs"],  # validated config dataclasses, model presets and field rules (no torch)
    ["lhf_hf.modeling"],
    ["lhf_hf.histories"],  # the dataset format, its card and Hub artifact
    ["lhf_hf.filtering"],  # LHF scores, selections (format, card, artifact)
    ["lhf_hf.collection"],
    ["lhf_hf.training"],
    ["lhf_hf.evaluation"],
    ["lhf_hf.hub", "lhf_hf.reproduce"],  # orchestration: push dispatch, paper experiments
    ["lhf_hf.verify"],  # lhf verify: manifests and each kind's deepest check
    ["lhf_hf.cli"],
    ["lhf_hf.__main__"],
]
LAYER = {name: i for i, names in enumerate(LAYERS) for name in names}


def _module(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _unit(module: str) -> str:
    """The layered unit of a module: the longest LAYER key that is a prefix of it."""
    parts = module.split(".")
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in LAYER:
            return ".".join(parts[:n])
    raise AssertionError(f"{module} is in no layer: add it to LAYERS")


def _imports(path: Path):
    """(imported lhf_hf module, line, at module level?) for every import in ``path``."""
    module = _module(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    tree = ast.parse(path.read_text())
    top = {id(n) for n in tree.body}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(base + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            # `from lhf_hf import constants` imports the submodule lhf_hf.constants
            names = [f"{base}.{a.name}" if base == "lhf_hf" else base for a in node.names]
        else:
            continue
        for name in names:
            if name == "lhf_hf" or name.startswith("lhf_hf."):
                yield name, node.lineno, id(node) in top


SOURCES = sorted(PACKAGE.rglob("*.py"))


def test_every_module_is_in_a_layer():
    for path in SOURCES:
        _unit(_module(path))


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_go_down_the_layers(path):
    me = _unit(_module(path))
    lines = path.read_text().splitlines()
    for name, line, at_top in _imports(path):
        them = _unit(name)
        if them != me:
            assert LAYER[them] < LAYER[me], (
                f"{path.name}:{line} imports {name} (layer {LAYER[them]}: {them}) from layer "
                f"{LAYER[me]} ({me}): a back-edge"
            )
        if not at_top:
            assert "# deferred:" in lines[line - 1], (
                f"{path.name}:{line}: a function-level import of {name} without a "
                "`# deferred: <reason>` comment (import it at the top: the layers have no cycle)"
            )


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_every_function_level_import_says_why(path):
    """Any import inside a function (lhf_hf's or a third party's) is deferred on purpose: an
    optional extra, or a heavy library a light path must not pay for; its line says which."""
    lines = path.read_text().splitlines()
    for fn in ast.walk(ast.parse(path.read_text())):
        if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.Import | ast.ImportFrom):
                text = " ".join(lines[node.lineno - 1 : node.end_lineno])
                assert "# deferred:" in text, (
                    f"{path.name}:{node.lineno}: `{lines[node.lineno - 1].strip()}` inside a "
                    "function without a `# deferred: <why>` comment"
                )


def test_the_layering_test_sees_a_back_edge(tmp_path):
    """The checker itself: an envs module importing training is reported."""
    bad = PACKAGE / "envs" / "_layering_probe.py"
    bad.write_text("from lhf_hf.training import train\n")
    try:
        with pytest.raises(AssertionError, match="back-edge"):
            test_imports_go_down_the_layers(bad)
    finally:
        bad.unlink()


def test_no_env_knowledge_outside_envs():
    """Everything the code asks about an environment is on its ``EnvSpec``: outside ``lhf_hf/envs``
    nothing reads ``spec.family`` or compares with an env id or family name."""
    from lhf_hf.envs import get_spec, list_env_ids

    names = set(list_env_ids()) | {get_spec(e).family for e in list_env_ids()}
    found = []
    for path in SOURCES:
        if path.is_relative_to(PACKAGE / "envs"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr == "family":
                found.append(f"{path.name}:{node.lineno} reads .family")
            if isinstance(node, ast.Compare):
                for operand in [node.left, *node.comparators]:
                    if isinstance(operand, ast.Constant) and operand.value in names:
                        found.append(f"{path.name}:{node.lineno} compares with {operand.value!r}")
    assert not found, found
