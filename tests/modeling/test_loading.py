"""``load_model`` loads a checkpoint exactly or refuses it in one line (never random heads)."""

from __future__ import annotations

import shutil

import pytest
import torch
from safetensors.torch import load_file, save_file

from lhf_hf.modeling import ICRLModel, icrl_config, load_model


@pytest.fixture()
def saved(tmp_path):
    model = ICRLModel(icrl_config("tiny", objective="dicp", env_id="darkroom", state_bins=9))
    model.save_pretrained(tmp_path / "ok")
    return tmp_path / "ok"


def _variant(saved, tmp_path, name, edit):
    out = tmp_path / name
    shutil.copytree(saved, out)
    weights = load_file(out / "model.safetensors")
    save_file(edit(weights), out / "model.safetensors", metadata={"format": "pt"})
    return out


def test_an_exact_checkpoint_loads_with_its_weights(saved):
    model = load_model(str(saved))
    stored = load_file(saved / "model.safetensors")
    assert all(torch.equal(model.state_dict()[k], v) for k, v in stored.items())


def test_missing_unexpected_and_misshaped_tensors_are_refused(saved, tmp_path):
    def drop_reward_head(w):
        return {k: v for k, v in w.items() if not k.startswith("reward_head")}

    with pytest.raises(ValueError, match=r"missing reward_head.bias, reward_head.weight"):
        load_model(str(_variant(saved, tmp_path, "missing", drop_reward_head)))
    with pytest.raises(ValueError, match=r"unexpected extra.weight"):
        load_model(
            str(_variant(saved, tmp_path, "extra", lambda w: {**w, "extra.weight": torch.ones(2)}))
        )
    with pytest.raises(ValueError, match=r"mis-shaped action_head.weight \[3, 3\]"):
        load_model(
            str(
                _variant(
                    saved,
                    tmp_path,
                    "shape",
                    lambda w: {**w, "action_head.weight": torch.ones(3, 3)},
                )
            )
        )


def test_a_config_naming_another_objective_is_refused(saved, tmp_path):
    """AD weights under a DICP config would evaluate randomly initialised dynamics heads."""
    ad = ICRLModel(icrl_config("tiny", objective="ad", env_id="darkroom", state_bins=9))
    ad.save_pretrained(tmp_path / "ad")
    shutil.copy(saved / "config.json", tmp_path / "ad" / "config.json")  # says dicp
    with pytest.raises(ValueError, match=r"do not fit its config.json \(dicp.*missing"):
        load_model(str(tmp_path / "ad"))


def test_a_truncated_weights_file_is_one_clear_error(saved):
    f = saved / "model.safetensors"
    f.write_bytes(f.read_bytes()[:100])
    with pytest.raises(ValueError, match="not a readable safetensors file"):
        load_model(str(saved))
