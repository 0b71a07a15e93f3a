"""Compile a C++ kernel on first use and cache the library: shared by the PPO-update kernel
(``lhf_hf.collection.native``) and the training attention kernel (``lhf_hf.modeling.attention_kernel``).

A kernel is compiled with the system's C++ compiler (``$CXX`` or ``g++``; ``-O3 -march=native``, so
it must be built on the machine that runs it) into a per-user cache (``$LHF_HF_KERNEL_CACHE``,
default ``~/.cache/lhf_hf/kernels``), keyed by the source, the flags, the compiler's version and what
``-march=native`` means on this CPU (the compiler's expansion of it; ``$LHF_HF_KERNEL_MARCH`` builds
another instruction set's path, see :func:`target_march`); the file is written under a temporary
name and renamed, so concurrent builds are safe.  A library is loaded only from a private cache
(owned by this user, writable by nobody else) and only when its SHA-256 equals the one recorded when
it was built: a missing, truncated, corrupt or foreign file is rebuilt, never loaded (``dlopen`` runs
a library's code, and a truncated one kills the process).  No compiler, or a failed build, raises
:class:`KernelUnavailable` with the reason; callers then fall back to their torch implementation.
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Callable
from pathlib import Path

from lhf_hf.errors import UserRuntimeError

from .io import sha256_file

logger = logging.getLogger(__name__)

FLAGS = (
    "-O3",
    "-std=gnu++17",
    "-fPIC",
    "-shared",
    "-fno-math-errno",
    "-mprefer-vector-width=512",
)


class KernelUnavailable(UserRuntimeError):
    """A C++ kernel cannot be built or loaded here (the message says why)."""


def cache_dir() -> Path:
    return Path(
        os.environ.get("LHF_HF_KERNEL_CACHE", Path.home() / ".cache" / "lhf_hf" / "kernels")
    )


def private_cache_dir() -> Path:
    """``cache_dir()``, created 0700, after checking that nobody else can write libraries into it."""
    path = cache_dir()
    path.mkdir(parents=True, exist_ok=True, mode=0o700)
    st = path.stat()
    if st.st_uid != os.getuid() or st.st_mode & 0o022:
        raise KernelUnavailable(
            f"the kernel cache {path} is not private (owner uid {st.st_uid}, mode "
            f"{oct(st.st_mode & 0o777)}): it must be yours and writable by you alone "
            f"(chmod 700 {path}), or set $LHF_HF_KERNEL_CACHE to such a folder"
        )
    return path


def target_march() -> str:
    """The ``-march`` kernels are built for: ``$LHF_HF_KERNEL_MARCH`` or ``native``.

    Another value builds another instruction set's code path on this CPU (e.g. ``haswell``, AVX2 +
    FMA, on an AVX-512 machine) to test and measure it where no such CPU is at hand; it is read at
    a process's first build (which refuses a value that is not a ``-march`` name); empty is
    ``native``."""
    return os.environ.get("LHF_HF_KERNEL_MARCH") or "native"


def native_target(cxx: str, march: str = "native") -> str:
    """The compiler's expansion of ``-march=MARCH`` (CPU model and every enabled feature)."""
    proc = subprocess.run(
        [cxx, f"-march={march}", "-Q", "--help=target"], capture_output=True, text=True
    )
    return proc.stdout


def open_verified(build: Callable[..., Path], *args) -> ctypes.CDLL:
    """Load the library the cached ``build(*args)`` returns; a copy whose bytes changed since this
    process built or checked it (``verified``) is built again first."""
    path = build(*args)
    if not verified(path):
        build.cache_clear()
        path = build(*args)
    return ctypes.CDLL(str(path))


def verified(lib: Path) -> bool:
    """The library exists and its bytes are the ones recorded when it was built."""
    record = lib.with_name(lib.name + ".sha256")
    try:
        return record.read_text().strip() == sha256_file(lib)
    except OSError:
        return False


def compiler(what: str = "the torch implementation") -> str:
    cxx = os.environ.get("CXX", "g++")
    if shutil.which(cxx) is None:
        raise KernelUnavailable(
            f"no C++ compiler {cxx!r} on PATH (set $CXX); {what} is used instead"
        )
    return cxx


def local_headers(source: Path) -> list[Path]:
    """The headers ``source`` includes from its own folder (``#include "name.h"``), recursively, in
    order of first inclusion: their text is part of the build key, so editing a shared header
    rebuilds every kernel that includes it."""
    found: list[Path] = []

    def scan(path: Path) -> None:
        for name in re.findall(r'^\s*#\s*include\s*"([^"]+)"', path.read_text(), re.MULTILINE):
            header = (path.parent / name).resolve()
            if header not in found:
                found.append(header)
                scan(header)

    scan(source)
    return found


def build_library(
    source: Path,
    stem: str,
    extra_flags: tuple[str, ...] = (),
    describe_target: Callable[[str, str], str] = native_target,
) -> Path:
    """Compile ``source`` into ``<cache>/<stem>-<key>.so`` unless a verified copy is cached; returns
    its path.  ``describe_target(cxx, march)``: what the ``-march`` means here (part of the key)."""
    cxx = compiler()
    march = target_march()
    if not re.fullmatch(r"[A-Za-z0-9_.+-]+", march):
        raise KernelUnavailable(f"$LHF_HF_KERNEL_MARCH must be a -march name, got {march!r}")
    version = subprocess.run([cxx, "--version"], capture_output=True, text=True).stdout
    flags = (*FLAGS, f"-march={march}", *extra_flags)
    key = hashlib.sha256(
        "\0".join(
            [
                source.read_text(),
                *(h.read_text() for h in local_headers(source)),
                " ".join(flags),
                version,
                os.uname().machine,
                describe_target(cxx, march),
            ]
        ).encode()
    ).hexdigest()[:16]
    out = private_cache_dir() / f"{stem}-{key}.so"
    if verified(out):
        return out
    if out.exists():
        logger.warning("%s does not match its recorded SHA-256: rebuilding it", out)
    fd, tmp = tempfile.mkstemp(dir=out.parent, suffix=".so.tmp")
    os.close(fd)
    try:
        proc = subprocess.run([cxx, *flags, "-o", tmp, str(source)], capture_output=True, text=True)
        if proc.returncode != 0:
            origin = "" if march == "native" else f" for -march={march} ($LHF_HF_KERNEL_MARCH)"
            raise KernelUnavailable(
                f"building {source.name}{origin} failed:\n{proc.stderr[-2000:]}"
            )
        digest = sha256_file(Path(tmp))
        os.replace(tmp, out)  # atomic: a concurrent build of the same key writes the same bytes
        record = out.with_name(out.name + ".sha256")
        fd, tmp_record = tempfile.mkstemp(dir=out.parent, suffix=".sha256.tmp")
        with os.fdopen(fd, "w") as f:
            f.write(digest + "\n")
        os.replace(tmp_record, record)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return out
