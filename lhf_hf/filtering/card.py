"""The card (README.md) of an LHF selection folder, from ``lhf_hf/templates/selection_card.md``."""

from __future__ import annotations

from pathlib import Path

from huggingface_hub import DatasetCard, DatasetCardData

from lhf_hf.utils.hub import public_source
from lhf_hf.utils.io import read_json
from lhf_hf.utils.templates import template_path

from .select import CONFIG_FILE, SCORES_FILE, SELECTION_FILE
from .within_task import describe


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.3f}"


def render_selection_card(
    path: str | Path, load_path: str | None = None, source: str | None = None
) -> str:
    """Card text of the selection folder ``path``; its snippets load it from ``load_path``;
    ``source``: the Hub repo its source dataset was pushed to (checked by the caller), in place of
    the recorded one."""
    path = Path(path)
    meta = read_json(path / CONFIG_FILE)
    flt, src, summary = meta["filter"], meta["source"], meta.get("summary", {})
    if source is not None:
        src = {**src, "path": source}
    env_id = src.get("env_id", "?")
    label = (
        f"LHF {flt['strategy']}" if flt["strategy"] in ("linear", "softmax") else flt["strategy"]
    )
    card_data = DatasetCardData(
        license="apache-2.0",
        pretty_name=f"{env_id} learning histories: {label} selection (lambda {flt['lam']})",
        tags=["lhf", "in-context-rl", "learning-history-filtering", env_id],
        task_categories=["reinforcement-learning"],
        configs=[
            {"config_name": "default", "data_files": SELECTION_FILE},
            {"config_name": "scores", "data_files": SCORES_FILE},
        ],
    )
    source = str(src.get("path", "?"))
    local = source.startswith("/")
    # the train command runs as written: a Hub source by its id; a local one by its path on this
    # machine, and in a pushed card (load_path given) by a placeholder the text explains
    dataset_arg = "DATASET" if local and load_path else source
    return DatasetCard.from_template(
        card_data,
        template_path=str(template_path("selection_card.md")),
        source=public_source(source) if load_path else f"`{source}`",
        dataset_arg=dataset_arg,
        dataset_note=(
            f"(`DATASET`: the source `{Path(source).name}` was a local folder; push it with "
            "`lhf push`, then name its repo here, or push this selection with `--source-repo`)"
            if dataset_arg == "DATASET"
            else ""
        ),
        env_id=env_id,
        strategy=flt["strategy"],
        lam=flt["lam"],
        alpha=flt["alpha"] if flt["strategy"] == "softmax" else "-",
        seed=flt["seed"],
        total=summary.get("histories", src.get("total_histories", "?")),
        kept=summary.get("selected_unique", "?"),
        max_count=summary.get("max_count", "?"),
        mean_source=_fmt(summary.get("mean_return_source")),
        mean_selection=_fmt(summary.get("mean_return_selection")),
        within=describe(summary.get("within_task"), long=True),
        fingerprint=str(src.get("fingerprint", "?"))[:16],
        versions=", ".join(f"{k} {v}" for k, v in meta.get("versions", {}).items()),
        load_path=load_path or str(path.resolve()),
    ).content
