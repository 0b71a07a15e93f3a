"""The kernels' build key covers the local headers a source includes: editing a shared header
(``modeling/kernels/simd.h``) rebuilds every kernel that includes it."""

from __future__ import annotations

import shutil

import pytest

from lhf_hf.utils import native_build


def test_local_headers_are_found_recursively_once(tmp_path):
    (tmp_path / "a.h").write_text('#pragma once\n#include "b.h"\n')
    (tmp_path / "b.h").write_text("#pragma once\n")
    src = tmp_path / "k.cpp"
    src.write_text('#include <cmath>\n#include "a.h"\n  # include "b.h"\nint f() { return 1; }\n')
    assert native_build.local_headers(src) == [tmp_path / "a.h", tmp_path / "b.h"]


@pytest.mark.skipif(shutil.which("g++") is None, reason="no C++ compiler")
def test_editing_an_included_header_rebuilds(tmp_path, monkeypatch):
    monkeypatch.setenv("LHF_HF_KERNEL_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("LHF_HF_KERNEL_MARCH", raising=False)
    header = tmp_path / "v.h"
    header.write_text("#pragma once\nconstexpr int kValue = 1;\n")
    src = tmp_path / "k.cpp"
    src.write_text('#include "v.h"\nextern "C" int value() { return kValue; }\n')
    first = native_build.build_library(src, "k")
    assert native_build.build_library(src, "k") == first  # cached
    header.write_text("#pragma once\nconstexpr int kValue = 2;\n")
    assert native_build.build_library(src, "k") != first


def test_the_kernels_include_the_shared_header():
    from lhf_hf.modeling import attention_kernel, tree_attention

    for source in (attention_kernel.SOURCE, tree_attention.SOURCE):
        assert [h.name for h in native_build.local_headers(source)] == ["simd.h"]
