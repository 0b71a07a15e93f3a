"""An LHF selection as the sampling counts a training draws its histories with."""

from __future__ import annotations

import hashlib

import numpy as np

from lhf_hf.errors import UserError
from lhf_hf.utils.hub import resolve, source_of
from lhf_hf.utils.io import sha256_file

from .select import SCORES_FILE, load_selection, source_mismatch


def selection_counts(selection_dir: str, ds, history_index: np.ndarray) -> tuple[np.ndarray, dict]:
    """(H,) counts of an LHF selection for the histories ``history_index`` (H,) of ``ds``, in that
    order, after checking that the selection was made from ``ds``; and what training records of it."""
    local = resolve(selection_dir, "dataset", "selection")
    sel = load_selection(local)
    if sel.source.get("fingerprint") is None:
        raise UserError(f"the selection {selection_dir} does not record its source dataset")
    for problem in source_mismatch(ds, sel):
        raise UserError(f"{selection_dir}: {problem}")
    counts = sel.counts()
    unknown = set(counts) - set(history_index.tolist())
    if unknown:
        raise UserError(f"the selection names {len(unknown)} histories that {ds.root} lacks")
    out = np.array([counts.get(int(h), 0) for h in history_index], np.int64)
    info = {
        "path": source_of(selection_dir, local),
        "fingerprint": sha256_file(local / SCORES_FILE),
        "counts_sha256": hashlib.sha256(out.tobytes()).hexdigest(),  # what training draws from
        "filter": sel.config.to_dict(),
        "selected_unique": int((out > 0).sum()),
        "total_count": int(out.sum()),
    }
    return out, info
