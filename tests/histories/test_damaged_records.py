"""A dataset's or a selection's JSON records with the wrong shapes (``[]``, ``null``, a string for a
number) are one ``UserError`` naming the file and the field, never a TypeError from deep inside."""

from __future__ import annotations

import json
import shutil

import pytest

from lhf_hf import constants as C
from lhf_hf.cli.main import main
from lhf_hf.configs import FilterConfig
from lhf_hf.errors import UserError
from lhf_hf.filtering import filter_histories, load_selection
from lhf_hf.histories import load_histories
from lhf_hf.histories.reader import DatasetFormatError
from lhf_hf.utils.outputs import MARKER

DAMAGE = [
    (C.INFO_PATH, "features", []),
    (C.INFO_PATH, "total_tasks", None),
    (C.INFO_PATH, "total_frames", "1200"),
    (C.LHF_INFO_PATH, "tasks", None),
    (C.LHF_INFO_PATH, "tasks", [3, "40"]),
    (C.LHF_INFO_PATH, "horizon", "x"),
    (C.LHF_INFO_PATH, "histories_per_task", None),
    (C.LHF_INFO_PATH, "env_id", 5),
]


@pytest.fixture
def copy(small_darkroom, tmp_path):
    root = tmp_path / "d"
    shutil.copytree(small_darkroom.root, root)
    return root


@pytest.mark.parametrize("manifest", [True, False], ids=["with-manifest", "no-manifest"])
@pytest.mark.parametrize(("rel", "field", "value"), DAMAGE)
def test_a_damaged_field_is_named(copy, rel, field, value, manifest):
    record = json.loads((copy / rel).read_text())
    record[field] = value
    (copy / rel).write_text(json.dumps(record))
    if not manifest:  # a folder without a manifest still gets the field checks
        (copy / MARKER).unlink()
    with pytest.raises(DatasetFormatError, match=rf"{rel}: damaged .*{field}="):
        load_histories(copy)


@pytest.mark.parametrize("top", ["[]", "null", '"text"'])
def test_a_record_that_is_not_an_object_is_named(copy, top):
    (copy / MARKER).unlink()  # the records' own checks, not the manifest's
    (copy / C.LHF_INFO_PATH).write_text(top)
    with pytest.raises(DatasetFormatError, match="lhf_info.json is damaged: not a JSON object"):
        load_histories(copy)
    (copy / C.INFO_PATH).write_text(top)
    with pytest.raises(DatasetFormatError, match="info.json is damaged: not a JSON object"):
        load_histories(copy)


@pytest.mark.parametrize(
    "marker", ["[]", "null", "{bad", '{"filter": 3}', '{"kind": "dataset", "files": []}']
)
def test_a_damaged_manifest_is_named_never_read_as_absent(copy, marker, capsys):
    from lhf_hf.verify import verify

    (copy / MARKER).write_text(marker)
    with pytest.raises(UserError, match="is damaged .not the manifest an lhf command writes"):
        load_histories(copy)
    with pytest.raises(UserError, match="is damaged"):
        verify(copy)
    assert main(["verify", str(copy)]) == 1
    assert "Traceback" not in capsys.readouterr().err


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        ("[]", "has no 'source' object"),
        ("null", "has no 'source' object"),
        ('{"filter": [], "source": {}}', "'filter' is list, not an object of FilterConfig"),
        ('{"filter": {"bogus": 1}, "source": {}}', "FilterConfig does not know (bogus)"),
        ('{"filter": {"strategy": "nope"}, "source": {}}', "'filter': FilterConfig.strategy"),
        ('{"filter": {"lam": "x"}, "source": {}}', "FilterConfig.lam must be a number"),
    ],
)
def test_a_damaged_filter_config_is_named(small_darkroom, tmp_path, content, needle, capsys):
    sel = filter_histories(small_darkroom, FilterConfig()).save(tmp_path / "sel")
    (sel / "filter_config.json").write_text(content)
    with pytest.raises(UserError, match=needle.replace("(", r"\(").replace(")", r"\)")):
        load_selection(sel)
    args = ["train", "--dataset", str(small_darkroom.root), "--selection", str(sel)]
    args += [
        "--objective",
        "ad",
        "--preset",
        "tiny",
        "--max-steps",
        "1",
        "--out",
        str(tmp_path / "m"),
    ]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "filter_config.json" in err
