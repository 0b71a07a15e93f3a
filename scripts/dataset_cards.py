"""``dataset_cards/``: the cards of the datasets and selections a reproduction makes, one per env
and collection protocol (run 0 of the shipped specs' ``cpu`` preset), so a reader sees each
dataset's contents, returns and settings without collecting it.

    python scripts/dataset_cards.py collect [--work runs/dataset_cards] [--only NAME ...]
    python scripts/dataset_cards.py render     # after a template change: from the kept metadata
    python scripts/dataset_cards.py check      # exit 1 when a card is not what lhf would write

``collect`` collects run 0's dataset of each entry of ``PUBLISHED`` with the stage config
``lhf reproduce`` uses (the PPO backend resolved, as a stage names it), filters it with the spec's
LHF arm, and keeps in ``dataset_cards/NAME/`` the card ``lhf push`` uploads for the repo
``YOUR_NAME/NAME``, its learning-curve PNG and the metadata files the card is made of
(``histories.card.CARD_SOURCES``: no frames); ``dataset_cards/NAME-lhf/`` keeps the selection's
card and its ``filter_config.json``. The selection's recorded source (a local folder of the
machine that collected it) is replaced there by the dataset's repo id, which is what a selection
made from the pushed dataset records: its card's ``lhf train`` command then names both repos.
``check`` renders every card again from the kept files with the installed templates (CI runs it).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

from lhf_hf import constants as C
from lhf_hf.collection import collect
from lhf_hf.collection.batched_collector import resolve_ppo_backend
from lhf_hf.filtering.card import render_selection_card
from lhf_hf.filtering.run import run_filter
from lhf_hf.filtering.select import CONFIG_FILE
from lhf_hf.histories.card import CARD_SOURCES, CardInputs, plot_card_curve, render_card_of
from lhf_hf.reproduce.experiment import load_experiment
from lhf_hf.utils.hub import public_contents
from lhf_hf.utils.io import write_bytes_atomic, write_text_atomic
from lhf_hf.utils.progress import library_bars

ROOT = Path(__file__).resolve().parents[1] / "dataset_cards"
OWNER = "YOUR_NAME"  # the repo owner the cards' snippets name: whoever pushes the data
PRESET = "cpu"
SELECTION_SUFFIX = "-lhf"


@dataclass(frozen=True)
class Published:
    """One dataset of a reproduction: run 0 of ``spec`` (preset ``cpu``) on ``env``."""

    name: str
    spec: str
    env: str

    @property
    def repo(self) -> str:
        return f"{OWNER}/{self.name}"


#: One per env and collection protocol the shipped specs collect at the cpu preset.
PUBLISHED = (
    Published("darkroom-paper", "darkroom-main", "darkroom"),
    Published("darkroom-noisy", "darkroom-noisy", "darkroom"),
    Published("darkroom-independent", "darkroom-main-independent", "darkroom"),
    Published("metaworld-reach-wall-ppo", "metaworld-ml1", "metaworld-reach-wall"),
    Published("metaworld-reach-sac", "metaworld-sac", "metaworld-reach"),
    Published("metaworld-push-sac", "metaworld-sac", "metaworld-push"),
)


def collect_config(item: Published):
    """The config of run 0's collection stage, resolved as ``lhf reproduce`` resolves it."""
    cfg = load_experiment(item.spec, PRESET).collect_config(item.env, 0)
    if cfg.collector == "batched":
        cfg.ppo_backend = resolve_ppo_backend(cfg)
    return cfg


def filter_config(item: Published):
    (arm, cfg), *rest = load_experiment(item.spec, PRESET).filter_arms(0)
    if rest or arm != "lhf":  # a sweep spec: not one of PUBLISHED's
        raise ValueError(f"{item.spec} sweeps its filter; publish one of its arms by name")
    return cfg


def render(item: Published, root: Path = ROOT) -> dict[Path, str]:
    """``{card path: text}`` of ``item``'s dataset and selection, from the files kept for them."""
    data, sel = root / item.name, root / f"{item.name}{SELECTION_SUFFIX}"
    return {
        data / C.CARD_PATH: render_card_of(CardInputs.read(data), item.repo),
        sel / C.CARD_PATH: render_selection_card(sel, f"{item.repo}{SELECTION_SUFFIX}"),
    }


def collect_command(item: Published, root: Path = ROOT) -> str:
    """The ``lhf collect`` call that makes the kept dataset again (same fingerprint): the spec's
    settings, and the PPO backend the collecting machine chose."""
    lhf = json.loads((root / item.name / C.LHF_INFO_PATH).read_text())
    settings = {k: v for k, v in load_experiment(item.spec, PRESET).collect.items() if k != "half"}
    if lhf["collect"]["collector"] == "batched":
        settings["ppo_backend"] = lhf["machine"]["ppo_backend"]
    flags = " ".join(f"--{k.replace('_', '-')} {v}" for k, v in settings.items())
    return f"lhf collect {item.env} {flags} --out {item.name}"


def index(root: Path = ROOT, items=PUBLISHED) -> str:
    """``dataset_cards/README.md``: one row per kept dataset."""
    rows = []
    for item in items:
        if not (root / item.name).is_dir():
            continue
        lhf = json.loads((root / item.name / C.LHF_INFO_PATH).read_text())
        sel = json.loads((root / f"{item.name}{SELECTION_SUFFIX}" / CONFIG_FILE).read_text())
        flt = sel["filter"]
        rows.append(
            f"| [{item.name}]({item.name}/README.md) | {item.spec} | {len(lhf['tasks'])} x "
            f"{lhf['histories_per_task']} x {lhf['steps_per_history']:,} | "
            f"`{lhf['fingerprint'][:12]}` | [LHF {flt['strategy']}, lambda {flt['lam']}]"
            f"({item.name}{SELECTION_SUFFIX}/README.md) | `{collect_command(item, root)}` |"
        )
    return "\n".join(
        [
            "# Dataset cards",
            "",
            f"The cards of the datasets `lhf reproduce SPEC --preset {PRESET}` collects in its run 0, one",
            "per env and collection protocol, and of their LHF selections: what `lhf push` uploads for",
            "each, so their contents, returns and settings are read without collecting them. The",
            f"snippets name the repos `{OWNER}/NAME` and `{OWNER}/NAME{SELECTION_SUFFIX}`: push a collected",
            f"folder with `lhf push FOLDER --repo-id {OWNER}/NAME`. Each folder keeps the card, the",
            "learning curve and the metadata files the card is made of (no frames).",
            "",
            "Made by `python scripts/dataset_cards.py collect` (the collections run as `lhf reproduce`",
            "runs them; `render` after a template change). CI (`tests/scripts/test_dataset_cards.py`)",
            "checks that every card is what the installed lhf_hf writes and that each spec still",
            "collects the data its card describes.",
            "",
            "| dataset | spec | tasks x histories x transitions | fingerprint | selection | collect it |",
            "|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )


def keep(item: Published, dataset: Path, selection: Path, root: Path = ROOT) -> None:
    """Copy what the cards are made of from a collected ``dataset`` and its ``selection``, then
    write the cards and the learning curve."""
    data, sel = root / item.name, root / f"{item.name}{SELECTION_SUFFIX}"
    for folder in (data, sel):
        shutil.rmtree(folder, ignore_errors=True)
    public = public_contents(dataset, list(CARD_SOURCES))  # as pushed: no path of this machine
    for rel in CARD_SOURCES:
        (data / rel).parent.mkdir(parents=True, exist_ok=True)
        if rel in public:
            write_bytes_atomic(public[rel], data / rel)
        else:
            shutil.copyfile(dataset / rel, data / rel)
    record = json.loads((selection / CONFIG_FILE).read_text())
    record["source"]["path"] = item.repo  # the pushed dataset, not this machine's folder
    sel.mkdir(parents=True)
    write_text_atomic(json.dumps(record, indent=2) + "\n", sel / CONFIG_FILE)
    plot_card_curve(CardInputs.read(data), data / C.CURVE_PATH)
    for path, text in render(item, root).items():
        write_text_atomic(text, path)
    write_text_atomic(index(root), root / C.CARD_PATH)


def changed_settings(item: Published, root: Path = ROOT) -> list[str]:
    """How the kept dataset's collection differs from what the spec's run 0 collects now (its
    PPO backend as recorded: the machine that collected chose it)."""
    lhf = json.loads((root / item.name / C.LHF_INFO_PATH).read_text())
    cfg = load_experiment(item.spec, PRESET).collect_config(item.env, 0)
    if cfg.collector == "batched":
        cfg.ppo_backend = lhf["machine"]["ppo_backend"]
    now, kept = cfg.identity(), lhf["collect"]
    return [f"{k}: {kept.get(k)!r} -> {now.get(k)!r}" for k in sorted(set(now) | set(kept))
            if now.get(k) != kept.get(k)]  # fmt: skip


def stale(root: Path = ROOT, items=PUBLISHED) -> list[str]:
    """What is out of date under ``root``: a card that differs from what the installed lhf_hf
    renders, a dataset the spec no longer collects."""
    out = []
    for item in items:
        if not (root / item.name).is_dir():
            out.append(f"{item.name}: not collected (python scripts/dataset_cards.py collect)")
            continue
        changed = changed_settings(item, root)
        if changed:
            out.append(f"{item.name}: {item.spec} collects other data now ({'; '.join(changed)}): "
                       f"python scripts/dataset_cards.py collect --only {item.name}")  # fmt: skip
        for path, text in render(item, root).items():
            if not path.is_file() or path.read_text() != text:
                out.append(
                    f"{path.relative_to(root)}: not what lhf_hf writes now "
                    "(python scripts/dataset_cards.py render)"
                )
    listing = root / C.CARD_PATH
    if items is PUBLISHED and (not listing.is_file() or listing.read_text() != index(root)):
        out.append(f"{C.CARD_PATH}: not the list of the kept cards (python "
                   "scripts/dataset_cards.py render)")  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("command", choices=["collect", "render", "check"])
    ap.add_argument("--work", default="runs/dataset_cards", help="where collections are made")
    ap.add_argument("--only", nargs="+", choices=[p.name for p in PUBLISHED], help="these only")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    items = [p for p in PUBLISHED if not args.only or p.name in args.only]
    if args.command == "check":
        problems = stale()
        for line in problems:
            print(f"dataset_cards: {line}", file=sys.stderr)
        return 1 if problems else 0
    if args.command == "render":
        for item in items:
            if (ROOT / item.name).is_dir():
                for path, text in render(item).items():
                    write_text_atomic(text, path)
        write_text_atomic(index(), ROOT / C.CARD_PATH)
        return 0
    for item in items:
        work = Path(args.work) / item.name
        dataset = work / "data"
        progress = not args.no_progress
        with library_bars(progress):
            collect(collect_config(item), dataset, resume=dataset.exists(), progress=progress)
            run_filter(dataset, work / "lhf", filter_config(item), overwrite=True,
                       progress=progress)  # fmt: skip
        keep(item, dataset, work / "lhf")
        print(f"{item.name}: {ROOT / item.name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
