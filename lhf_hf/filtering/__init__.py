"""Learning history filtering (paper section 4, Algorithm 1; docs/design.md section 5)."""

from .materialize import apply_selection, filter_frames, materialize
from .resample import algorithm1
from .sampling import sampling_probabilities
from .scores import improvement, stability, unified_score
from .select import Selection, filter_histories, lhf_resample, load_selection, score_histories

__all__ = [
    "Selection",
    "algorithm1",
    "apply_selection",
    "filter_frames",
    "filter_histories",
    "improvement",
    "lhf_resample",
    "load_selection",
    "materialize",
    "sampling_probabilities",
    "score_histories",
    "stability",
    "unified_score",
]
