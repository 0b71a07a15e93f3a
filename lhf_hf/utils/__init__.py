"""The bottom layer: atomic file io, library versions, Hub access (repo id -> local folder, one-commit
uploads), card templates, the build cache of the C++ kernels.  Imports only ``lhf_hf.constants``
and ``lhf_hf.errors`` (tests/test_layering.py)."""
