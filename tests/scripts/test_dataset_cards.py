"""dataset_cards/: each published dataset's card is what ``lhf push`` uploads for it, made from the
metadata kept beside it, of the data the spec's run 0 collects; the committed ones are current."""

from __future__ import annotations

import json
import shlex
import shutil

import pytest

from lhf_hf import constants as C
from lhf_hf.cli.flags import values
from lhf_hf.cli.main import build_parser
from lhf_hf.configs import CollectConfig, FilterConfig
from lhf_hf.filtering.run import run_filter
from lhf_hf.histories import load_histories
from lhf_hf.histories.card import render_card
from lhf_hf.reproduce.experiment import load_experiment
from lhf_hf.reproduce.reproduce import plan_stages
from tests.scripts import load_script

cards = load_script("dataset_cards")


def test_the_committed_cards_are_what_lhf_writes_of_what_the_specs_collect():
    assert cards.stale() == []


def test_the_kept_task_tables_name_the_registry_s_split():
    """Each kept ``meta/tasks.parquet`` marks train, validation and test tasks as the registry
    splits them now (the validation rule changing leaves no card naming the old goals)."""
    import pyarrow.parquet as pq

    from lhf_hf.envs import get_spec

    kept = [item for item in cards.PUBLISHED if (cards.ROOT / item.name).is_dir()]
    assert kept
    for item in kept:
        meta = cards.ROOT / item.name
        lhf = json.loads((meta / C.LHF_INFO_PATH).read_text())
        spec, seed = get_spec(lhf["env_id"]), lhf["split_seed"]
        train, validation = set(spec.split(seed)[0]), set(spec.validation_split(seed)[1])
        table = pq.read_table(meta / C.TASKS_PATH).to_pydict()
        want = [("validation" if t in validation else "train") if t in train else "test"
                for t in table["task_id"]]  # fmt: skip
        assert table["split"] == want, item.name


def test_the_listed_collect_command_makes_the_kept_dataset():
    """Each card's ``lhf collect`` command (dataset_cards/README.md) parses to the config whose
    identity the kept dataset records: the same fingerprint, collected again."""
    parser = build_parser()
    kept = [item for item in cards.PUBLISHED if (cards.ROOT / item.name).is_dir()]
    for item in kept:
        command = cards.collect_command(item)
        assert f"`{command}`" in (cards.ROOT / C.CARD_PATH).read_text()
        args = parser.parse_args(shlex.split(command)[1:])
        config = CollectConfig(**values(args, args.config))
        lhf = json.loads((cards.ROOT / item.name / C.LHF_INFO_PATH).read_text())
        assert config.identity() == lhf["collect"], item.name


def test_each_published_dataset_is_a_collection_stage_of_its_spec(tmp_path):
    """The script collects what ``lhf reproduce`` collects for run 0 (one stage config)."""
    for item in cards.PUBLISHED:
        stages, _ = plan_stages(load_experiment(item.spec, cards.PRESET, runs=1), tmp_path,
                                progress=False)  # fmt: skip
        collect = [s for s in stages if s.kind == "collect" and s.config["env_id"] == item.env]
        assert [s.config for s in collect] == [cards.collect_config(item).identity()], item.name
        assert cards.filter_config(item) == FilterConfig(
            **load_experiment(item.spec, cards.PRESET).filter
        )


@pytest.fixture
def kept(learned_darkroom, tmp_path):
    """A small real collection and its selection, kept as ``collect`` keeps a published one."""
    item = cards.Published("darkroom-small", "darkroom-main", "darkroom")
    run_filter(learned_darkroom.root, tmp_path / "sel", FilterConfig(), progress=False)
    root = tmp_path / "cards"
    cards.keep(item, learned_darkroom.root, tmp_path / "sel", root)
    return item, root


def test_a_kept_card_is_the_pushed_card_and_names_no_local_path(kept, learned_darkroom, tmp_path):
    item, root = kept
    card = (root / item.name / C.CARD_PATH).read_text()
    assert card == render_card(load_histories(learned_darkroom.root), "YOUR_NAME/darkroom-small")
    assert (root / item.name / C.CURVE_PATH).read_bytes()[:4] == b"\x89PNG"
    assert not (root / item.name / "data").exists()  # metadata only, no frames
    sel_card = (root / f"{item.name}-lhf" / C.CARD_PATH).read_text()
    assert (
        "lhf train --dataset YOUR_NAME/darkroom-small --selection YOUR_NAME/darkroom-small-lhf"
        in sel_card
    )
    for path in root.rglob("*"):
        if path.suffix in (".md", ".json"):
            assert str(tmp_path) not in path.read_text() and "/work/" not in path.read_text(), path
        if path.suffix == ".json":  # no absolute path at all (e.g. the PPO verdict's cache file)
            assert '"/' not in path.read_text(), path
    record = json.loads((root / f"{item.name}-lhf" / "filter_config.json").read_text())
    assert record["source"]["path"] == "YOUR_NAME/darkroom-small"
    assert record["source"]["fingerprint"] == learned_darkroom.fingerprint


def test_a_card_out_of_date_is_named(kept, monkeypatch):
    item, root = kept
    # the small collection is not the spec's: its settings are named, field by field
    (problem,) = cards.stale(root, [item])
    assert "darkroom-small: darkroom-main collects other data now (" in problem
    assert "histories: 4 -> 100" in problem and "--only darkroom-small" in problem
    monkeypatch.setattr(cards, "changed_settings", lambda item, root: [])
    assert cards.stale(root, [item]) == []
    card = root / item.name / C.CARD_PATH
    card.write_text(card.read_text().replace("histories per task", "runs per task"))
    (problem,) = cards.stale(root, [item])
    assert problem.startswith("darkroom-small/README.md: not what lhf_hf writes now")
    for path, text in cards.render(item, root).items():
        path.write_text(text)
    assert cards.stale(root, [item]) == []
    shutil.rmtree(root / item.name)
    assert cards.stale(root, [item]) == [
        "darkroom-small: not collected (python scripts/dataset_cards.py collect)"
    ]
