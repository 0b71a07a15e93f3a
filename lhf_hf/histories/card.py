"""The dataset card (README.md) of a learning-history dataset, from ``lhf_hf/templates/``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from huggingface_hub import DatasetCard, DatasetCardData

from lhf_hf import constants as C
from lhf_hf.envs import get_spec
from lhf_hf.utils.hub import public_source
from lhf_hf.utils.io import read_json, write_text_atomic
from lhf_hf.utils.templates import template_path

from .plots import learning_curves, plot_learning_curve

COLUMN_MEANING = {
    C.OBS: "state the action was taken in",
    C.ACTION: "executed action (continuous: after clipping)",
    C.REWARD: "reward of the transition",
    C.DONE: "last step of the episode (the horizon)",
    C.NEXT_OBS: "true next state (the final state at an episode end, not the reset state)",
    C.OPTIMAL_ACTION: "oracle action in `observation.state` (DPT label)",
    C.SUCCESS: "the env's success flag after the step",
    C.INDEX: "global frame index",
    C.FRAME_INDEX: "step within the episode",
    C.EPISODE_INDEX: "global episode index",
    C.TASK_INDEX: "row of the task in meta/tasks.parquet (LeRobot's dense task index)",
    C.TASK_ID: "the env's own task number (what `lhf collect --tasks` names)",
    C.HISTORY_INDEX: "global history index (see meta/histories)",
    C.TIMESTAMP: f"frame_index / fps (fps = {C.FPS})",
}


def _fmt(x: float) -> str:
    return f"{x:.2f}"


#: The files a card is made of (the dataset's metadata, not its frames or episodes):
#: ``dataset_cards/`` keeps these beside each published dataset's card.
CARD_SOURCES = (C.INFO_PATH, C.LHF_INFO_PATH, C.TASKS_PATH, C.HISTORIES_PATH)


@dataclass(frozen=True)
class CardInputs:
    """What a dataset card is rendered from: ``info.json``, ``lhf_info.json`` and the tasks and
    histories tables."""

    info: dict
    lhf: dict
    tasks: pa.Table
    histories: pa.Table

    @property
    def env_id(self) -> str:
        return self.lhf["env_id"]

    @classmethod
    def of(cls, ds) -> CardInputs:
        """Of a ``HistoryDataset``."""
        return cls(ds.info, ds.lhf, ds.tasks.data.table, ds.histories.data.table)

    @classmethod
    def read(cls, root: str | Path) -> CardInputs:
        """From the ``CARD_SOURCES`` files under ``root`` (a dataset, or a copy of its metadata)."""
        root = Path(root)
        info, lhf, tasks, hist = (root / rel for rel in CARD_SOURCES)
        return cls(read_json(info), read_json(lhf), pq.read_table(tasks), pq.read_table(hist))


def render_card(ds, load_path: str | None = None) -> str:
    """Render the card text of dataset ``ds`` (a ``HistoryDataset``)."""
    # a local card names its folder absolute, as the selection and model cards do: it is read
    # from anywhere, and a relative path would be relative to where the collection ran
    return render_card_of(CardInputs.of(ds), load_path, local_root=ds.root.resolve())


def render_card_of(
    inputs: CardInputs, load_path: str | None = None, local_root: Path | None = None
) -> str:
    """The card text from its inputs; its snippets load the data from ``load_path`` (a repo id),
    else from the folder ``local_root``."""
    if load_path is None and local_root is None:
        raise ValueError("render_card_of needs a load_path or the dataset's local_root")
    lhf, info = inputs.lhf, inputs.info
    spec = get_spec(inputs.env_id)
    derived = lhf.get("derived_from")
    # a derived dataset (a materialised selection) was collected as its source was
    collect = lhf.get("collect") or (derived or {}).get("source_collect") or {}
    algo = str(collect.get("algo", "unknown algorithm")).upper()
    n_tasks = info["total_tasks"]
    size = info["total_frames"]
    size_cat = next(
        c
        for lim, c in [
            (1e3, "n<1K"),
            (1e4, "1K<n<10K"),
            (1e5, "10K<n<100K"),
            (1e6, "100K<n<1M"),
            (1e7, "1M<n<10M"),
            (1e8, "10M<n<100M"),
            (1e9, "100M<n<1B"),
            (np.inf, "n>1B"),
        ]
        if size < lim
    )
    card_data = DatasetCardData(
        license="apache-2.0",
        pretty_name=f"{inputs.env_id} learning histories ({', '.join(_kind(collect, derived, algo))})",
        task_categories=["reinforcement-learning"],
        tags=["LeRobot", "lhf", "in-context-rl", "learning-histories", inputs.env_id],
        size_categories=[size_cat],
        configs=[
            {"config_name": "default", "data_files": "data/*/*.parquet"},
            {"config_name": "episodes", "data_files": "meta/episodes/*/*.parquet"},
            {"config_name": "histories", "data_files": "meta/histories/*/*.parquet"},
        ],
    )
    tasks = inputs.tasks.to_pandas()
    hist = inputs.histories
    returns = hist.column(C.RETURNS).to_pylist()
    task_of = hist.column(C.TASK_ID).to_numpy()
    optimal = spec.optimal_returns() if spec.optimal_returns is not None else None
    rows = []
    for t, split in zip(tasks[C.TASK_ID], tasks[C.SPLIT], strict=True):
        r = np.asarray([returns[i] for i in np.flatnonzero(task_of == t)])  # (H, E)
        rows.append(
            {
                "task": int(t),
                "split": split,
                "first": _fmt(r[:, 0].mean()),
                "last": _fmt(r[:, -1].mean()),
                "best": _fmt(r.max()),
                "optimal": _fmt(optimal[t]) if optimal is not None else "-",
            }
        )
    note = ""
    if len(rows) > 40:
        note = f" The first 40 of {len(rows)} tasks are shown; the histories table has them all."
        rows = rows[:40]
    kinds = hist.column(C.LEARNER).to_pylist()
    # totals over the dataset: a selection changes the mix task by task
    learner_counts = ", ".join(f"{k} {kinds.count(k)}" for k in dict.fromkeys(kinds))
    schema = [
        {
            "name": name,
            "dtype": f["dtype"],
            "shape": tuple(f["shape"]),
            "meaning": COLUMN_MEANING.get(name, ""),
        }
        for name, f in info["features"].items()
    ]
    settings = _settings(collect)
    how = (
        _how_collected(collect, lhf)
        if collect
        else f"Derived from another dataset; its settings are in `{C.LHF_INFO_PATH}`."
    )
    derived_note = ""
    if derived:
        derived_note = (
            f"> **Derived dataset** (`{derived['op']}`): {derived['description']} "
            f"Source: {public_source(derived['source'])} (fingerprint "
            f"`{derived['source_fingerprint'][:16]}`)."
        )
    versions = ", ".join(f"{k} {v}" for k, v in lhf.get("versions", {}).items())
    n_train = int((tasks[C.SPLIT] != "test").sum())  # validation tasks are train tasks
    n_validation = int((tasks[C.SPLIT] == "validation").sum())
    card = DatasetCard.from_template(
        card_data,
        template_path=str(template_path("histories_card.md")),
        pretty_name=card_data.pretty_name,
        algo_name=algo,
        env_id=inputs.env_id,
        env_description=spec.description,
        derived_note=derived_note,
        total_tasks=n_tasks,
        n_train=n_train,
        n_validation=n_validation,
        # a Hub repo at the tag LeRobot readers use (a branch name makes datasets ask the Hub's
        # dataset viewer first, docs/hub.md); a local folder has no revision
        revision_arg=f', revision="{C.CODEBASE_VERSION}"' if load_path else "",
        n_test=n_tasks - n_train,
        split_seed=lhf["split_seed"],
        histories=lhf["histories_per_task"],
        learner_counts=learner_counts,
        steps=lhf["steps_per_history"],
        episodes_per_history=lhf["episodes_per_history"],
        horizon=lhf["horizon"],
        total_frames=info["total_frames"],
        fingerprint=lhf["fingerprint"],
        curve_path=C.CURVE_PATH,
        how_collected=how,
        settings=settings,
        versions=versions,
        schema=schema,
        task_rows=rows,
        task_table_note=note,
        load_path=load_path or str(local_root),
        lerobot_line=(
            f'ds = LeRobotDataset("{load_path}")'
            if load_path
            else f'ds = LeRobotDataset("local/{local_root.name}", root="{local_root}")'
        ),
    )
    return str(card)


def _settings(collect: dict) -> list[tuple[str, object]]:
    """The collection settings that made the data: the task list is in the tasks table, and the
    settings of the algorithm, protocol and collector that did not run are left out."""
    algo, protocol = collect.get("algo"), collect.get("protocol")
    unused = {"tasks", *({"ppo", "sac"} - {algo})}
    if protocol != "noisy":
        unused.add("noisy_fraction")
    if protocol != "learners":
        unused.add("learners")
    if algo != "ppo" or collect.get("collector") != "batched":
        unused.add("ppo_backend")  # only the batched collector's PPO has backends
    return [(k, v) for k, v in collect.items() if k not in unused]


def _kind(collect: dict, derived: dict | None, algo: str) -> list[str]:
    """What the card's title says of the data: algorithm, protocol, and how it was derived."""
    out = [algo]
    if collect.get("protocol"):
        out.append(str(collect["protocol"]))
    if derived:
        out.append(str(derived.get("op", "derived")))
    return out


def _how_collected(collect: dict, lhf: dict) -> str:
    protocol = collect.get("protocol")
    H = collect.get("histories")
    desc = {
        "paper": f"one {collect.get('algo', '').upper()} learner per task acting in {H} parallel copies of the task "
        f"({'SB3 `DummyVecEnv`' if collect.get('collector') == 'sb3' else 'stepped together by the batched collector'}); "
        "each copy's stream of transitions is one history (the reference protocol).",
        "independent": f"{H} independently seeded {collect.get('algo', '').upper()} learners per task, one stream each.",
        "learners": f"{collect.get('learners')} independently seeded {collect.get('algo', '').upper()} learners per "
        f"task, each acting in {H // max(1, collect.get('learners') or 1)} parallel copies of the task; each copy's "
        "stream is one history (histories differ between learners, each learner learns from several streams).",
        "noisy": f"as `paper`, but {round(collect.get('noisy_fraction', 0.3) * 100)}% of each task's histories come "
        "from a uniform random policy on their own copies of the task (they never feed the learner's "
        "updates); the logged action is the executed action.",
    }.get(protocol, str(protocol))
    return (
        f"Protocol `{protocol}`: {desc} Collector: `{collect.get('collector')}`. Task t's learners are "
        f"seeded from `SeedSequence([{collect.get('seed')}, t])`. Terminal convention: "
        f"{lhf.get('terminal_convention', 'truncation')}."
    )


def plot_card_curve(inputs: CardInputs, path: Path) -> None:
    """The card's learning-curve PNG: the mean return per episode over all histories."""
    spec = get_spec(inputs.env_id)
    optimal = None
    if spec.optimal_returns is not None:
        tasks = inputs.tasks.column(C.TASK_ID).to_numpy()
        optimal = float(spec.optimal_returns()[tasks].mean())
    plot_learning_curve(
        learning_curves(inputs.histories.to_pydict()),
        path,
        title=f"{inputs.env_id}: return per episode over {inputs.lhf['total_histories']} histories",
        optimal=optimal,
    )


def write_card(ds, load_path: str | None = None) -> None:
    """Write the learning-curve PNG and README.md of ``ds``."""
    plot_card_curve(CardInputs.of(ds), ds.root / C.CURVE_PATH)
    write_text_atomic(render_card(ds, load_path), ds.root / C.CARD_PATH)
