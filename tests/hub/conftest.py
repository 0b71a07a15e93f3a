"""Fixtures of the Hub tests: the protocol fake (uploads) and olah (reads) over one git store."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).parent


@pytest.fixture(scope="session")
def hub_store(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("hub-store")


@pytest.fixture(scope="session")
def fake_hub(hub_store):
    from .fake_hub import FakeHub

    hub = FakeHub(hub_store)
    hub.endpoint = hub.serve()
    yield hub
    hub.close()


@pytest.fixture(scope="session")
def olah(hub_store, tmp_path_factory):
    pytest.importorskip(
        "olah", reason="olah is in the hub-test extra: pip install -e '.[hub-test]'"
    )
    from .olah_server import OlahServer

    server = OlahServer(hub_store, tmp_path_factory.mktemp("olah"))
    endpoint = server.start()
    yield endpoint
    server.stop()


@pytest.fixture
def hub_client(tmp_path):
    """``hub_client(endpoint, code, *args, token=..., python=...)``: run ``code`` in a fresh Python
    process (``python``: another venv's interpreter, e.g. LeRobot's) whose
    HF_ENDPOINT / HF_HOME / HF_HUB_DISABLE_XET are set before any import, under the loopback guard
    of ``_client.py``.  Returns the CompletedProcess (stdout/stderr as text)."""
    counter = iter(range(1000))

    def run(
        endpoint: str | None,
        code: str,
        *args: str,
        token: str | None = "hf_fake_token",
        python: str = sys.executable,
    ):
        script = tmp_path / f"client_{next(counter)}.py"
        script.write_text(code)
        env = {
            k: v
            for k, v in os.environ.items()
            if not k.startswith(("HF_", "HUGGINGFACE_")) and k not in ("http_proxy", "https_proxy")
        }
        env.update(HF_HOME=str(tmp_path / "hf_home"), HF_HUB_DISABLE_XET="1")
        env["HF_HUB_DISABLE_TELEMETRY"] = "1"
        # datasets.load_dataset otherwise pings s3.amazonaws.com to count downloads (the loopback
        # guard caught it): off, as every offline user should have it.
        env["HF_UPDATE_DOWNLOAD_COUNTS"] = "0"
        env["PYTHONPATH"] = os.pathsep.join([str(HERE.parents[1]), env.get("PYTHONPATH", "")])
        if endpoint is not None:
            env["HF_ENDPOINT"] = endpoint
        if token is not None:
            env["HF_TOKEN"] = token
        return subprocess.run(
            [python, str(HERE / "_client.py"), str(script), *args],
            env=env,
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=600,
        )

    return run
