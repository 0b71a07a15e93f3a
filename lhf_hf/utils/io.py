"""Atomic file writes: a crash never leaves a half-written file under its final name."""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from lhf_hf.errors import MissingFieldError, UserError


def _umask() -> int:
    mask = os.umask(0o022)  # reading the umask means setting it: set it back at once
    os.umask(mask)
    return mask


#: The process's file-creation mask, read once (``os.umask`` cannot read without writing).
_UMASK = _umask()


class Fields(dict):
    """A JSON object read from a file: a missing field is a ``MissingFieldError`` that names the
    file (damaged, or not written by lhf_hf), not a bare ``KeyError`` that reads as a bug."""

    def __init__(self, pairs, source: Path):
        super().__init__(pairs)
        self.source = source

    def __missing__(self, key):
        raise MissingFieldError(
            f"{self.source} has no field {key!r}: the file is damaged or not written by lhf_hf"
        )


def read_json(path: str | os.PathLike):
    """The JSON value in ``path``, its objects as ``Fields``; a malformed file is a ``UserError``
    naming it (json's own message gives only a line and column)."""
    path = Path(path)
    text = path.read_text()
    try:
        return json.loads(text, object_pairs_hook=lambda pairs: Fields(pairs, path))
    except ValueError as exc:
        raise UserError(
            f"{path} is not valid JSON ({exc}): the file is damaged or not ours"
        ) from None


def give_umask_mode(path: str | os.PathLike) -> None:
    """Give a file written by another library the mode a new file gets (``0o666 & ~umask``):
    safetensors writes its files through a 0600 temporary, whatever the umask."""
    os.chmod(path, 0o666 & ~_UMASK)


def _tmp_for(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    # mkstemp creates 0600; the renamed file should have the mode any new file gets (0644 at umask 022)
    os.fchmod(fd, 0o666 & ~_UMASK)
    os.close(fd)
    return Path(tmp)


def write_parquet_atomic(table: pa.Table, path: str | os.PathLike) -> str:
    """Write ``table`` to ``path`` via a temporary file and ``os.replace``; return its sha256."""
    path = Path(path)
    tmp = _tmp_for(path)
    try:
        pq.write_table(table, tmp)
        digest = sha256_file(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return digest


def write_bytes_atomic(data: bytes, path: str | os.PathLike) -> None:
    path = Path(path)
    tmp = _tmp_for(path)
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_json_atomic(obj, path: str | os.PathLike) -> None:
    write_bytes_atomic(
        (json.dumps(obj, indent=2, sort_keys=False, default=_json_default) + "\n").encode(), path
    )


def write_text_atomic(text: str, path: str | os.PathLike) -> None:
    write_bytes_atomic(text.encode(), path)


def _json_default(o):
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def sha256_file(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def parquet_num_rows(path: str | os.PathLike) -> int | None:
    """Rows of a parquet file, or None when it is missing or unreadable (corrupt/truncated)."""
    try:
        return pq.ParquetFile(path).metadata.num_rows
    except (OSError, pa.ArrowException, ValueError):
        return None


def save_figure_atomic(fig, path: str | os.PathLike) -> None:
    """Save a matplotlib figure via a temporary file, then close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = (
        path.parent / f".{path.stem}.{os.getpid()}.tmp{path.suffix}"
    )  # savefig picks the format by suffix
    try:
        fig.savefig(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
        import matplotlib.pyplot as plt  # deferred: 0.5 s; the figure's owner imported it already

        plt.close(fig)
