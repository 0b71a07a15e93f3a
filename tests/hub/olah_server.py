"""Start olah (a self-hosted Hugging Face Hub mirror, from PyPI) on 127.0.0.1 in offline mode.

olah serves the git repos under ``mirrors`` (``{models,datasets}/ORG/NAME``) through the Hub's read
API (repo info, tree, paths-info, refs, resolve), which is what ``snapshot_download``,
``datasets.load_dataset`` and ``AutoModel.from_pretrained`` call.  Offline mode: it never contacts
an upstream (and its upstream is pointed at a closed loopback port, to be sure).
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class OlahServer:
    def __init__(self, mirrors: Path, workdir: Path):
        self.mirrors, self.workdir = Path(mirrors), Path(workdir)
        self.port = free_port()
        self.endpoint = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen | None = None

    def start(self, timeout: float = 60.0) -> str:
        self.workdir.mkdir(parents=True, exist_ok=True)
        config = self.workdir / "olah.toml"
        config.write_text(
            "[basic]\n"
            'host = "127.0.0.1"\n'
            f"port = {self.port}\n"
            f'repos-path = "{self.workdir / "cache"}"\n'
            f'mirrors-path = ["{self.mirrors}"]\n'
            'hf-scheme = "http"\n'
            'hf-netloc = "127.0.0.1:9"\n'  # upstream: a closed port (offline mode never calls it)
            'hf-lfs-netloc = "127.0.0.1:9"\n'
            f'mirror-netloc = "127.0.0.1:{self.port}"\n'
            f'mirror-lfs-netloc = "127.0.0.1:{self.port}"\n'
            "metadata-cache-ttl = 0\n"  # re-pushed repos must be seen at once
            "[accessibility]\n"
            "offline = true\n"
        )
        exe = shutil.which("olah-cli", path=str(Path(sys.executable).parent)) or "olah-cli"
        self.log = open(self.workdir / "olah.out", "wb")
        self.proc = subprocess.Popen(
            [exe, "-c", str(config), "--log-path", str(self.workdir / "logs")],
            cwd=self.workdir,
            stdout=self.log,
            stderr=subprocess.STDOUT,
        )
        deadline = time.time() + timeout
        while time.time() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(
                    f"olah exited: {(self.workdir / 'olah.out').read_text()[-2000:]}"
                )
            try:  # any HTTP answer (even an error status) means the server is up
                urllib.request.urlopen(self.endpoint + "/api/datasets/x/y/refs", timeout=1)  # noqa: S310
                return self.endpoint
            except urllib.error.HTTPError:
                return self.endpoint
            except OSError:
                time.sleep(0.3)
        self.stop()
        raise RuntimeError(f"olah did not start within {timeout} s")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        if getattr(self, "log", None):
            self.log.close()
