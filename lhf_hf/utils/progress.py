"""``--no-progress`` beyond lhf's own bars: the ones the libraries draw themselves.

lhf's bars (collection, derive, filter, evaluation) and Trainer's (``disable_tqdm``) take a
command's ``progress`` argument; transformers, datasets and huggingface_hub draw theirs from their
own global switches, which ``library_bars(False)`` turns off for the length of a command.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def library_bars(enabled: bool) -> Iterator[None]:
    """``--no-progress`` for the bars the libraries draw themselves: transformers (loading and
    writing weights), datasets (building tables) and huggingface_hub (uploads, downloads); each
    put back as it was afterwards.  lhf's own bars and Trainer's take the command's ``progress``."""
    if enabled:
        yield
        return
    import datasets  # deferred: heavy, and only when asked
    from huggingface_hub import utils as hub_utils  # deferred: as above
    from transformers.utils import logging as hf_logging  # deferred: as above

    switches = [  # (was on, off, on)
        (hf_logging.is_progress_bar_enabled(), hf_logging.disable_progress_bar,
         hf_logging.enable_progress_bar),
        (datasets.is_progress_bar_enabled(), datasets.disable_progress_bars,
         datasets.enable_progress_bars),
        (not hub_utils.are_progress_bars_disabled(), hub_utils.disable_progress_bars,
         hub_utils.enable_progress_bars),
    ]  # fmt: skip
    for _, off, _ in switches:
        off()
    try:
        yield
    finally:
        for was_on, _, on in switches:
            if was_on:
                on()
