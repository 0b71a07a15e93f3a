"""README.md's Python quickstart runs as written (in an empty folder) and reports a return."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.mark.slow
def test_the_python_quickstart_runs_as_written(tmp_path):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert len(blocks) == 1
    done = subprocess.run([sys.executable, "-c", blocks[0]], cwd=tmp_path, capture_output=True,
                          text=True, timeout=900, check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    mean_return = float(done.stdout.strip().splitlines()[-1])
    assert 0.0 <= mean_return <= 20.0  # Darkroom's returns: 0 .. the horizon
    assert (tmp_path / "sel" / "py" / "selection.parquet").is_file()
    assert (tmp_path / "runs" / "ad-lhf-py" / "eval" / "eval_results.json").is_file()
