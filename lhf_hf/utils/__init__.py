"""The bottom layer: atomic file io, library versions, Hub access (repo id -> local folder, one-commit
uploads), card templates.  Imports only ``lhf_hf.constants`` (tests/test_layering.py)."""
