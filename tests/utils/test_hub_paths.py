"""What ``lhf push`` uploads names no absolute path of the machine that made the artifact."""

import hashlib
import json

from lhf_hf.utils.hub import public_contents, pushed_manifest
from lhf_hf.utils.outputs import record_manifest


def test_absolute_paths_in_json_records_become_local_names(tmp_path):
    (tmp_path / "filter_config.json").write_text(
        json.dumps(
            {"source": {"path": "/home/alice/data/dr", "fingerprint": "ab"}, "n": [1, "/x/y"]}
        )
    )
    (tmp_path / "hub.json").write_text(json.dumps({"source": {"path": "org/ds@0123"}}))
    (tmp_path / "notes.json").write_text('{"a": "/not valid json')
    (tmp_path / "table.csv").write_text("/home/alice\n")
    record_manifest(tmp_path, "selection")
    files = ["filter_config.json", "hub.json", "notes.json", "table.csv"]
    public = public_contents(tmp_path, files)
    assert list(public) == ["filter_config.json"]  # the others hold no path it may rewrite
    assert json.loads(public["filter_config.json"]) == {
        "source": {"path": "local:dr", "fingerprint": "ab"},
        "n": [1, "local:y"],
    }
    manifest = json.loads(pushed_manifest(tmp_path, files, public))
    sha = hashlib.sha256(public["filter_config.json"]).hexdigest()
    assert manifest["files"]["filter_config.json"] == sha  # the pushed bytes, not the local ones
    local = hashlib.sha256((tmp_path / "hub.json").read_bytes()).hexdigest()
    assert manifest["files"]["hub.json"] == local
