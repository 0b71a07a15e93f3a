"""A checkpoint of ``lhf train`` loads with transformers alone, in a venv that has torch,
transformers and safetensors (the versions of ``requirements.lock``) but not lhf_hf, and computes
what lhf_hf's own model computes on the same input.

The venv is built on first use into ``.venv-clean/`` (git-ignored; a few minutes, once) and reused
while ``requirements.lock`` and the Python version are those it was built from.  It is a plain
``python -m venv`` (no ``--system-site-packages``: an lhf_hf installed in the base interpreter
stays invisible), and the script runs in isolated mode (``-I``: no ``PYTHONPATH``, no user site,
not the source tree), asserting that lhf_hf cannot be imported.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file

from lhf_hf.modeling import AUTO_MAP, load_model

from .test_remote_code import _inputs

REPO = Path(__file__).resolve().parents[2]
LOCK = REPO / "requirements.lock"
CLEAN_VENV = REPO / ".venv-clean"
#: installed from requirements.lock with their dependencies (as the lock pins them), nothing else
PACKAGES = ("torch", "transformers", "safetensors")


def _pins() -> list[str]:
    pins = [
        line
        for line in LOCK.read_text().splitlines()
        if line.split("==")[0].strip().lower() in PACKAGES
    ]
    assert len(pins) == len(PACKAGES), pins
    return pins


def _build_key() -> str:
    """What the venv was built from: the lock (the pins and their dependencies') and the Python."""
    return f"{hashlib.sha256(LOCK.read_bytes()).hexdigest()[:16]} {sys.version.split()[0]}"


@pytest.fixture(scope="module")
def clean_python() -> Path:
    """The Python of ``.venv-clean``, built (or rebuilt, when its key is stale) under a lock."""
    python, stamp = CLEAN_VENV / "bin" / "python", CLEAN_VENV / ".lhf-clean-install"
    log = REPO / ".venv-clean.install.log"
    with open(REPO / ".venv-clean.lock", "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)  # one build at a time (parallel test runs)
        if stamp.is_file() and stamp.read_text() == _build_key() and python.is_file():
            return python
        if CLEAN_VENV.exists():
            if not (CLEAN_VENV / "pyvenv.cfg").is_file():  # not a venv: not ours to delete
                pytest.fail(f"{CLEAN_VENV} exists and is not a venv: move it away")
            shutil.rmtree(CLEAN_VENV)
        with open(log, "w") as out:
            for cmd in (
                [sys.executable, "-m", "venv", str(CLEAN_VENV)],
                [str(python), "-m", "pip", "install", "-c", str(LOCK), *_pins()],
                [str(python), "-m", "pip", "check"],
            ):
                out.write(f"$ {' '.join(cmd)}\n")
                out.flush()
                rc = subprocess.run(cmd, stdout=out, stderr=subprocess.STDOUT).returncode
                if rc:
                    pytest.fail(f"building {CLEAN_VENV} failed ({cmd[2:4]}): see {log}")
        stamp.write_text(_build_key())  # last: an interrupted build is rebuilt
    return python


TRANSFORMERS_ALONE = r"""
import importlib.metadata, importlib.util, json, sys
assert sys.flags.isolated and importlib.util.find_spec("lhf_hf") is None, sys.path
try:
    import lhf_hf  # noqa: F401
    raise SystemExit("lhf_hf is importable")
except ModuleNotFoundError:
    pass
import torch
from safetensors.torch import load_file, save_file
from transformers import AutoConfig, AutoModel

model_dir, checkpoint_dir = sys.argv[1], sys.argv[2]
config = AutoConfig.from_pretrained(model_dir, trust_remote_code=True)
model = AutoModel.from_pretrained(model_dir, trust_remote_code=True).eval()
with torch.no_grad():
    out = model(**load_file("inputs.safetensors"))
save_file({k: v for k, v in out.items() if isinstance(v, torch.Tensor)}, "outputs.safetensors")
# a training checkpoint-N loads the same way; a re-save (transformers copies the code it loaded)
# loads again
ckpt = AutoModel.from_pretrained(checkpoint_dir, trust_remote_code=True)
model.save_pretrained("resaved")
again = AutoModel.from_pretrained("resaved", trust_remote_code=True)
print(json.dumps({
    "classes": [type(x).__module__ + "." + type(x).__name__ for x in (config, model, ckpt, again)],
    "objective": config.objective,
    "same_weights": all(torch.equal(again.state_dict()[k], v) for k, v in model.state_dict().items()),
    "versions": {p: importlib.metadata.version(p) for p in ("torch", "transformers", "safetensors")},
    "lhf_hf_loaded": sorted(m for m in sys.modules if m.split(".")[0] == "lhf_hf"),
}))
"""


@pytest.mark.slow
def test_transformers_alone_loads_a_trained_checkpoint_and_computes_what_lhf_hf_computes(
    tiny_model, clean_python, tmp_path
):
    checkpoint = tiny_model / "checkpoint-2"
    for folder in (tiny_model, checkpoint):
        assert json.loads((folder / "config.json").read_text())["auto_map"] == AUTO_MAP
    ours = load_model(str(tiny_model))
    assert ours.config.attention == "band" and ours.config.context_length == 8
    x = _inputs(ours.config, T=20)  # more transitions than the context: band attention
    save_file(x, tmp_path / "inputs.safetensors")
    with torch.no_grad():
        expected = {k: v for k, v in ours(**x).items() if isinstance(v, torch.Tensor)}
    (tmp_path / "transformers_alone.py").write_text(TRANSFORMERS_ALONE)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "HF_"))}
    env.update(HF_HOME=str(tmp_path / "hf_home"), HF_HUB_OFFLINE="1")
    proc = subprocess.run(
        [str(clean_python), "-I", "transformers_alone.py", str(tiny_model), str(checkpoint)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, f"{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["lhf_hf_loaded"] == [] and got["objective"] == "dicp" and got["same_weights"]
    for cls in got["classes"]:  # transformers' copies of the checkpoint's code
        assert cls.startswith("transformers_modules."), cls
    assert got["versions"] == dict(pin.split("==") for pin in _pins())
    outputs = load_file(tmp_path / "outputs.safetensors")
    assert set(outputs) == set(expected)
    assert {"loss", "action_logits", "reward_logits", "next_state_logits"} <= set(outputs)
    for k, v in expected.items():
        assert torch.equal(outputs[k], v), k
