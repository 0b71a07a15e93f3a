"""Datasets derived from a history dataset.  ``half``: the first part of every history (paper,
"Can LHF enhance ICRL given partial learning histories?", first 50%)."""

from __future__ import annotations

from pathlib import Path

from tqdm.auto import tqdm

from .reader import load_histories
from .writer import finalize, is_complete, library_versions, prepare_output, task_done, write_task


def derive_half(
    src: str | Path,
    out: str | Path,
    *,
    fraction: float = 0.5,
    overwrite: bool = False,
    resume: bool = False,
    progress: bool = True,
):
    """Write the first ``fraction`` of every history of ``src`` (whole episodes) to ``out``.

    The new dataset keeps tasks, histories and learners; its ``info.json`` records the source path,
    fingerprint and collection config under ``lhf.derived_from``.
    """
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction must be in (0, 1), got {fraction!r}")
    source = load_histories(src)
    horizon = source.horizon
    steps = source.lhf["steps_per_history"]
    new_steps = int(steps * fraction) // horizon * horizon  # whole episodes only
    if new_steps < horizon:
        raise ValueError(
            f"{fraction:.0%} of {steps} steps is less than one episode ({horizon} steps)"
        )
    tasks = [int(t) for t in source.lhf["tasks"]]
    H = source.lhf["histories_per_task"]
    identity = {"op": "half", "fraction": fraction, "source_fingerprint": source.fingerprint}
    out = Path(out)
    if resume and is_complete(out):
        prepare_output(out, identity, resume=True)
        return load_histories(out)
    prepare_output(out, identity, resume=resume, overwrite=overwrite)
    todo = [p for p in range(len(tasks)) if not task_done(out, p, H * new_steps)]
    for p in tqdm(todo, desc="derive half", unit="task", disable=not progress):
        write_task(out, p, source.task_histories(tasks[p]).slice_steps(new_steps), horizon)
    meta = {
        k: v
        for k, v in source.lhf.items()
        if k
        not in (
            "collect",
            "fingerprint",
            "created",
            "derived_from",
            "histories_per_task",
            "steps_per_history",
            "episodes_per_history",
            "horizon",
            "env_id",
            "split_seed",
        )
    }
    meta["versions"] = library_versions()
    meta["derived_from"] = {
        "op": "half",
        "fraction": fraction,
        "description": f"the first {new_steps} of the {steps} transitions of every history "
        f"({new_steps // horizon} of {steps // horizon} episodes).",
        "source": str(Path(src).resolve()),
        "source_fingerprint": source.fingerprint,
        "source_collect": source.lhf.get("collect")
        or (source.lhf.get("derived_from") or {}).get("source_collect"),
    }
    features = source.info["features"]
    names = {k: v["names"] for k, v in features.items() if v.get("names")}
    return finalize(
        out,
        env_id=source.env_id,
        tasks=tasks,
        histories=H,
        steps=new_steps,
        horizon=horizon,
        lhf_meta=meta,
        split_seed=source.lhf["split_seed"],
        feature_names=names,
    )
