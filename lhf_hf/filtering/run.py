"""``run_filter``: the importable body of ``lhf filter`` (selection, plot, optional materialisation)."""

from __future__ import annotations

import time
from pathlib import Path

from lhf_hf import constants as C
from lhf_hf.configs.filter import FilterConfig
from lhf_hf.histories.reader import load_histories
from lhf_hf.histories.writer import DATASET_FILES
from lhf_hf.utils.io import write_text_atomic
from lhf_hf.utils.outputs import output_folder, preflight

from .card import render_selection_card
from .materialize import materialize as materialize_histories
from .plots import plot_selection
from .select import CONFIG_FILE, PLOT_FILE, filter_histories


def run_filter(
    dataset: str | Path,
    out: str | Path,
    config: FilterConfig,
    *,
    materialize: str | Path | None = None,
    overwrite: bool = False,
    progress: bool = True,
) -> dict:
    """Filter ``dataset`` with ``config``; write the selection to ``out`` (and, with
    ``materialize``, the selected histories with their repeats as a dataset in that folder).

    Returns the summary (counts, learner shares, mean returns of selected vs rejected, timings).
    """
    out = Path(out)
    if materialize is not None:  # refuse a bad --materialize before the selection is written
        preflight(
            materialize,
            "dataset",
            overwrite=overwrite,
            inputs=[dataset, out],
            legacy=DATASET_FILES,
        )  # not resumable: `lhf filter` has no --resume (an error suggesting it named no flag)
    # The selection and the dataset materialised from it change together: an interrupt at any
    # instant leaves both new or both old (utils.outputs, linked / defer_to).
    linked: list = []
    with output_folder(
        out,
        "selection",
        overwrite=overwrite,
        inputs=[dataset, materialize],
        legacy=[CONFIG_FILE],
        linked=linked,
    ):
        return _filter_into(dataset, out, config, materialize, overwrite, progress, linked)


def _filter_into(
    dataset, out: Path, config, materialize, overwrite: bool, progress: bool, linked: list
) -> dict:
    ds = load_histories(dataset)
    start = time.perf_counter()
    selection = filter_histories(ds, config)
    seconds = time.perf_counter() - start
    returns = ds.by_history(C.RETURNS)
    summary = {**selection.summary(returns), "selection_seconds": round(seconds, 4)}
    selection.save(out, summary)
    write_text_atomic(render_selection_card(out), out / C.CARD_PATH)
    label = (
        config.strategy
        if config.strategy in ("none", "top-fraction")
        else f"LHF {config.strategy}, lambda={config.lam}"
        + (f", alpha={config.alpha}" if config.strategy == "softmax" else "")
    )
    plot_selection(selection.table, returns, out / PLOT_FILE, title=f"{ds.env_id}: {label}")
    if materialize is not None:
        start = time.perf_counter()
        materialize_histories(
            ds,
            selection,
            materialize,
            overwrite=overwrite,
            progress=progress,
            inputs=[out],
            extra_files={f"meta/{PLOT_FILE}": out / PLOT_FILE},  # before its manifest
            defer_to=linked,
        )
        summary["materialize_seconds"] = round(time.perf_counter() - start, 3)
        selection.save(out, summary)
    return summary
