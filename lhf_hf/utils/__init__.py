"""The bottom layer: atomic file io, library versions, Hub access (repo id -> local folder, one-commit
uploads), card templates.  Imports nothing else from lhf_hf (tests/test_layering.py)."""
