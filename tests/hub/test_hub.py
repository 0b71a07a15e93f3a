"""Hub round trips (issue 7), all on 127.0.0.1: uploads go to the protocol fake (fake_hub.py), reads
go through olah serving the very git repos the fake wrote.  Every client runs in its own process
with HF_ENDPOINT / HF_HOME / HF_HUB_DISABLE_XET set before any import and a guard that aborts on
any non-loopback connection (exit code 97)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml

pytestmark = pytest.mark.hub

LOOPBACK_VIOLATION = 97
REPO = Path(__file__).resolve().parents[2]


def _ok(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode != LOOPBACK_VIOLATION, (
        f"a request left 127.0.0.1:\n{proc.stderr[-3000:]}"
    )
    assert proc.returncode == 0, (
        f"rc={proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    )
    return proc.stdout


def _fails(proc: subprocess.CompletedProcess, *needles: str) -> str:
    assert proc.returncode != LOOPBACK_VIOLATION, (
        f"a request left 127.0.0.1:\n{proc.stderr[-3000:]}"
    )
    assert proc.returncode != 0, proc.stdout[-2000:]
    for n in needles:
        assert n in proc.stderr, f"{n!r} not in:\n{proc.stderr[-3000:]}"
    return proc.stderr


def _interrupt_and_wait(pid: int, deadline_s: float = 60.0) -> None:
    """Ctrl-C the client, then hold the server's answer until the client has exited (or 60 s).
    Answering at once races the signal: a loaded machine could deliver the refusal first, and the
    client would report the refusal instead of the interrupt."""
    os.kill(pid, signal.SIGINT)
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        try:  # the client is the test's child: once it exits it stays a zombie until reaped
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (FileNotFoundError, ProcessLookupError):
            return
        if state in ("Z", "X"):
            return
        time.sleep(0.05)


def _last_json(stdout: str) -> dict:
    return json.loads(stdout.strip().splitlines()[-1])


def _git(repo, *args) -> str:
    return subprocess.run(
        ["git", "-C", str(repo), *args], capture_output=True, text=True, check=True
    ).stdout.strip()


CLI = "import sys\nfrom lhf_hf.cli.main import main\nsys.exit(main(sys.argv[1:]))\n"

PUSH = """
import json, sys
from lhf_hf.hub import push
print(json.dumps(push(sys.argv[1], sys.argv[2])))
"""


def _card_meta(text: str) -> dict:
    return yaml.safe_load(text.split("---")[1])


@pytest.fixture(scope="module")
def checkpoint(small_darkroom_batched, tmp_path_factory):
    """A selection and a tiny AD model trained with it, both local."""
    from lhf_hf.configs import FilterConfig, TrainConfig
    from lhf_hf.filtering.run import run_filter
    from lhf_hf.training import train

    root = tmp_path_factory.mktemp("artifacts")
    run_filter(small_darkroom_batched.root, root / "sel", FilterConfig(), progress=False)
    cfg = TrainConfig(
        dataset=str(small_darkroom_batched.root),
        selection=str(root / "sel"),
        objective="ad",
        out=str(root / "ad"),
        preset="tiny",
        max_steps=4,
        batch_size=4,
        save_steps=4,
        logging_steps=2,
    )
    train(cfg)
    return root


# ---------------------------------------------------------------------------- datasets
@pytest.mark.slow
def test_history_dataset_round_trip(small_darkroom_batched, fake_hub, olah, hub_client, tmp_path):
    ds = small_darkroom_batched
    repo = "lhf-test/darkroom-small"
    out = _ok(hub_client(fake_hub.endpoint, CLI, "push", str(ds.root), "--repo-id", repo))
    result = json.loads(out[: out.rindex("}") + 1])
    assert result["kind"] == "histories" and result["tag"] == "v3.0"

    # What the fake received, as git: one commit on top of the Hub's initial one, tagged v3.0.
    git_repo = fake_hub.repo_path("datasets", *repo.split("/"))
    assert _git(git_repo, "rev-list", "--count", "main") == "2"
    assert _git(git_repo, "rev-parse", "v3.0^{commit}") == _git(git_repo, "rev-parse", "main")
    assert _git(git_repo, "rev-parse", "main") == result["commit"]
    card = (git_repo / "README.md").read_text()
    meta = _card_meta(card)
    assert {"LeRobot", "lhf", "in-context-rl"} <= set(meta["tags"])
    assert [c["config_name"] for c in meta["configs"]] == ["default", "episodes", "histories"]
    assert f'load_dataset("{repo}", split="train", revision="v3.0")' in card  # the repo, not a path
    assert str(ds.root) not in card

    # Read back through olah with datasets, and with load_histories.
    load = f"""
import json
import datasets
import pyarrow.parquet as pq
from lhf_hf.histories import load_histories
out = {{}}
# At the codebase-version tag, as LeRobot loads it.  (On "main", datasets also asks the Hub's
# dataset viewer at datasets-server.<endpoint host> for exported infos: a DNS lookup that would
# leave this machine, so the loopback guard would stop it.)
for name in ("default", "episodes", "histories"):
    d = datasets.load_dataset("{repo}", name, split="train", revision="v3.0")
    d.data.table.to_pandas().to_parquet(f"{{name}}.parquet")
    out[name] = len(d)
h = load_histories("{repo}")
pq.write_table(h.frame_table(), "frames.parquet")
out["source"] = h.source
out["info"] = h.info
print(json.dumps(out))
"""
    got = _last_json(_ok(hub_client(olah, load)))
    assert got["source"] == f"{repo}@{result['commit']}"
    assert got["info"] == ds.info
    frames = ds.frame_table()
    assert got["default"] == frames.num_rows == ds.info["total_frames"]
    assert pq.read_table(tmp_path / "frames.parquet").equals(frames)
    # datasets' default config holds the same rows (its file order is its own: sort by index)
    default = pq.read_table(tmp_path / "default.parquet").sort_by("index")
    for col in ("index", "action", "next.reward", "history_index", "observation.state"):
        assert default.column(col).to_pylist() == frames.column(col).to_pylist(), col
    hist = pq.read_table(tmp_path / "histories.parquet").sort_by("history_index")
    local = ds.histories.data.table.sort_by("history_index")
    assert hist.column("returns").to_pylist() == local.column("returns").to_pylist()
    assert got["episodes"] == ds.episodes.num_rows


@pytest.mark.slow
def test_re_push_mirrors_the_folder_and_moves_the_tag(
    small_darkroom_batched, fake_hub, hub_client, tmp_path
):
    from lhf_hf.utils.outputs import record_manifest

    repo = "lhf-test/darkroom-repush"
    copy = tmp_path / "copy"
    shutil.copytree(small_darkroom_batched.root, copy)
    (copy / "meta" / "notes.txt").write_text("first version\n")
    record_manifest(copy, "dataset")  # an artifact whose command wrote the notes too
    first = _last_json(_ok(hub_client(fake_hub.endpoint, PUSH, str(copy), repo)))
    (copy / "meta" / "notes.txt").unlink()
    record_manifest(copy, "dataset")
    second = _last_json(_ok(hub_client(fake_hub.endpoint, PUSH, str(copy), repo)))
    assert second["deleted"] == 1 and first["commit"] != second["commit"]
    git_repo = fake_hub.repo_path("datasets", *repo.split("/"))
    assert "meta/notes.txt" not in _git(git_repo, "ls-files").splitlines()
    assert _git(git_repo, "tag") == "v3.0"
    assert _git(git_repo, "rev-parse", "v3.0^{commit}") == second["commit"]


# ---------------------------------------------------------------------------- selection, checkpoint
@pytest.mark.slow
def test_selection_and_checkpoint_round_trip(
    small_darkroom_batched, checkpoint, fake_hub, olah, hub_client, tmp_path
):
    from safetensors.numpy import load_file

    ds_repo, sel_repo, model_repo = "lhf-test/small", "lhf-test/small-lhf-sel", "lhf-test/small-ad"
    for path, repo in (
        (small_darkroom_batched.root, ds_repo),
        (checkpoint / "sel", sel_repo),
        (checkpoint / "ad", model_repo),
    ):
        res = _last_json(_ok(hub_client(fake_hub.endpoint, PUSH, str(path), repo)))
        assert res["repo_type"] == ("model" if repo == model_repo else "dataset")
    model_git = fake_hub.repo_path("models", *model_repo.split("/"))
    files = set(_git(model_git, "ls-files").splitlines())
    assert {"config.json", "model.safetensors", "train_config.json", "README.md"} <= files
    assert not any(f.startswith("checkpoint-") for f in files)  # optimizer states stay local
    card = (model_git / "README.md").read_text()
    assert f'AutoModel.from_pretrained("{model_repo}", trust_remote_code=True)' in card
    sel_card = (fake_hub.repo_path("datasets", *sel_repo.split("/")) / "README.md").read_text()
    assert _card_meta(sel_card)["configs"][0]["data_files"] == "selection.parquet"
    # no path of this machine in anything pushed with the dataset or the selection
    for repo in (ds_repo, sel_repo):
        git_repo = fake_hub.repo_path("datasets", *repo.split("/"))
        for f in _git(git_repo, "ls-files").splitlines():
            if f.endswith((".md", ".json")):
                text = (git_repo / f).read_text()
                assert (
                    str(checkpoint) not in text and str(small_darkroom_batched.root) not in text
                ), f

    load = f"""
import json
import lhf_hf.modeling
from safetensors.torch import save_file
from transformers import AutoModel
from lhf_hf.filtering import load_selection
m = AutoModel.from_pretrained("{model_repo}")
save_file({{k: v.contiguous() for k, v in m.state_dict().items()}}, "reloaded.safetensors")
sel = load_selection("{sel_repo}")
print(json.dumps({{"counts": sel.counts(), "objective": m.config.objective}}))
"""
    got = _last_json(_ok(hub_client(olah, load)))
    assert got["objective"] == "ad"
    from lhf_hf.filtering import load_selection

    local_counts = load_selection(checkpoint / "sel").counts()
    assert {int(k): v for k, v in got["counts"].items()} == local_counts
    before = load_file(checkpoint / "ad" / "model.safetensors")
    after = load_file(tmp_path / "reloaded.safetensors")
    assert before.keys() == after.keys()
    for k in before:
        assert (before[k] == after[k]).all(), k

    # The CLI by repo id: filter, train (dataset + selection), evaluate, all through olah.
    _ok(hub_client(olah, CLI, "filter", ds_repo, "--out", "sel2"))
    assert pq.read_table(tmp_path / "sel2" / "scores.parquet").equals(
        pq.read_table(checkpoint / "sel" / "scores.parquet")
    )
    _ok(
        hub_client(
            olah, CLI, "train", "--dataset", ds_repo, "--selection", sel_repo, "--objective", "ad",
            "--preset", "tiny", "--max-steps", "2", "--batch-size", "4", "--out", "ad2",
        )
    )  # fmt: skip
    prov = json.loads((tmp_path / "ad2" / "train_config.json").read_text())
    assert prov["dataset"]["path"].startswith(f"{ds_repo}@")
    assert prov["selection"]["path"].startswith(f"{sel_repo}@")
    assert prov["dataset"]["fingerprint"] == small_darkroom_batched.fingerprint
    _ok(
        hub_client(
            olah, CLI, "evaluate", "--model", model_repo, "--tasks", "38", "--episodes", "2",
            "--out", "ev",
        )
    )  # fmt: skip
    res = json.loads((tmp_path / "ev" / "eval_results.json").read_text())
    assert res["model"]["path"].startswith(f"{model_repo}@")
    assert len(res["returns"]) == 1 and len(res["returns"][0]) == 2


@pytest.mark.slow
def test_a_selection_names_its_pushed_source(
    small_darkroom, small_darkroom_batched, checkpoint, fake_hub, olah, hub_client
):
    """`lhf push SELECTION --source-repo`: the source dataset's repo is checked (fingerprints),
    pinned at its commit and named in the card's train command, which runs as written, and in the
    pushed record; a repo that does not hold the selection's source is refused, nothing pushed."""
    ds_repo, sel_repo = "lhf-test/sourced", "lhf-test/sourced-lhf"
    ds = _last_json(
        _ok(hub_client(fake_hub.endpoint, PUSH, str(small_darkroom_batched.root), ds_repo))
    )
    other = "lhf-test/other-data"
    _ok(hub_client(fake_hub.endpoint, PUSH, str(small_darkroom.root), other))
    sel = str(checkpoint / "sel")
    _fails(
        hub_client(fake_hub.endpoint, CLI, "push", sel, "--repo-id", sel_repo, "--source-repo", other),
        f"{other}@", "is not the dataset", "fingerprint", "not pushed",
    )  # fmt: skip
    _fails(
        hub_client(fake_hub.endpoint, CLI, "push", str(small_darkroom.root), "--repo-id", other,
                   "--source-repo", ds_repo),
        "only a selection names",
    )  # fmt: skip
    assert not fake_hub.repo_path("datasets", *sel_repo.split("/")).exists()

    _ok(hub_client(fake_hub.endpoint, CLI, "push", sel, "--repo-id", sel_repo,
                   "--source-repo", ds_repo))  # fmt: skip
    git_repo = fake_hub.repo_path("datasets", *sel_repo.split("/"))
    pinned = f"{ds_repo}@{ds['commit']}"
    card = (git_repo / "README.md").read_text()
    assert f"--dataset {pinned} --selection {sel_repo} " in card and "DATASET" not in card
    assert json.loads((git_repo / "filter_config.json").read_text())["source"]["path"] == pinned
    command = next(line for line in card.splitlines() if line.startswith("lhf train "))
    _ok(hub_client(olah, CLI, *command.split()[1:], "--preset", "tiny", "--max-steps", "2",
                   "--batch-size", "4", "--no-progress"))  # fmt: skip


@pytest.mark.slow
def test_train_push_to_hub(small_darkroom_batched, fake_hub, hub_client, tmp_path):
    from lhf_hf.modeling import MODEL_CODE_FILES

    repo = "lhf-test/trained-while-pushing"
    proc = hub_client(
        fake_hub.endpoint, CLI, "train", "--dataset", str(small_darkroom_batched.root),
        "--objective", "dicp", "--preset", "tiny", "--max-steps", "4", "--save-steps", "2",
        "--batch-size", "4", "--out", "run", "--push-to-hub", repo, "--no-progress",
    )  # fmt: skip
    _ok(proc)
    # --no-progress holds for the uploads too (Trainer's saving turns the Hub's bars back on)
    assert "%|" not in proc.stderr and "it/s" not in proc.stderr, proc.stderr[-2000:]
    git_repo = fake_hub.repo_path("models", *repo.split("/"))
    log = _git(git_repo, "log", "--format=%s").splitlines()
    assert any(s.startswith("Training in progress, step 2") for s in log)  # Trainer, every save
    assert log[0] == "lhf train: final model, step 4"
    files = set(_git(git_repo, "ls-files").splitlines())
    assert {"model.safetensors", "config.json", "train_config.json", "training_loss.png"} <= files
    card = (git_repo / "README.md").read_text()
    assert "lhf_hf" in _card_meta(card)["tags"]  # our card, not Trainer's generic one
    assert f'AutoModel.from_pretrained("{repo}", trust_remote_code=True)' in card
    # every commit, the per-save ones included: the model code, and no path of this machine
    for rev in _git(git_repo, "rev-list", "--all").splitlines()[
        :-1
    ]:  # the last: the repo's creation
        tree = _git(git_repo, "ls-tree", "--name-only", rev).splitlines()
        assert set(MODEL_CODE_FILES) <= set(tree), rev
    assert _grep_history(git_repo, str(tmp_path)) == []
    # `--out run` (relative, meaningless elsewhere) recorded absolute, so the push names it local
    assert json.loads((git_repo / "train_config.json").read_text())["train"]["out"] == "local:run"
    assert json.loads((git_repo / "training_args.json").read_text())["output_dir"] == "local:run"
    pushed = (git_repo / "model.safetensors").read_bytes()
    assert pushed == (tmp_path / "run" / "model.safetensors").read_bytes()


def _grep_history(git_repo, needle: str) -> list[str]:
    """``rev:path`` of every file, in every commit of ``git_repo``, that contains ``needle``."""
    revs = _git(git_repo, "rev-list", "--all").splitlines()
    proc = subprocess.run(["git", "-C", str(git_repo), "grep", "-l", "-F", needle, *revs],
                          capture_output=True, text=True)  # fmt: skip
    assert proc.returncode in (0, 1), proc.stderr  # 1: no match
    return proc.stdout.split()


TRANSFORMERS_ALONE = """
import json, sys
from transformers import AutoConfig, AutoModel
got = []
for repo in sys.argv[1:]:
    config = AutoConfig.from_pretrained(repo, trust_remote_code=True)
    model = AutoModel.from_pretrained(repo, trust_remote_code=True)
    got.append([type(config).__module__, type(model).__module__, config.objective])
assert not [m for m in sys.modules if m.split(".")[0] == "lhf_hf"]
from lhf_hf.modeling import load_model  # and lhf's strict load (the snapshot against its manifest)
for repo in sys.argv[1:]:
    assert type(load_model(repo)).__module__ == "lhf_hf.modeling.modeling_icrl"
print(json.dumps(got))
"""
PUSH_ALL = """
import sys
from lhf_hf.hub import push
for path, repo in zip(sys.argv[1::2], sys.argv[2::2]):
    push(path, repo)
"""


@pytest.mark.slow
def test_a_pushed_model_carries_its_code_and_no_local_path(
    small_darkroom_batched, checkpoint, fake_hub, olah, hub_client, tmp_path, tmp_path_factory
):
    """What `lhf push` uploads for a model: the code beside the weights (added to a checkpoint
    saved before checkpoints carried it), transformers alone loads it from the Hub, and no file
    names a folder of this machine (the dataset, the selection, the model, an evaluation)."""
    from lhf_hf.configs import EvalConfig
    from lhf_hf.evaluation import evaluate
    from lhf_hf.modeling import AUTO_MAP, MODEL_CODE_FILES
    from lhf_hf.training.card import MODEL_EVALS_FILE
    from lhf_hf.utils.outputs import record_manifest

    model = tmp_path / "ad"
    shutil.copytree(checkpoint / "ad", model)
    evaluate(
        EvalConfig(model=str(model), out=str(tmp_path / "ev"), tasks="38", episodes=2),
        progress=False,
    )
    assert str(tmp_path / "ev") in (model / MODEL_EVALS_FILE).read_text()
    repo, old_repo = "lhf-test/ad-no-paths", "lhf-test/ad-saved-without-code"
    old = tmp_path / "old"  # a checkpoint saved before checkpoints carried their code
    shutil.copytree(checkpoint / "ad", old)
    for name in MODEL_CODE_FILES:
        (old / name).unlink()
    config = json.loads((old / "config.json").read_text())
    del config["auto_map"]
    (old / "config.json").write_text(json.dumps(config, indent=2))
    marker = json.loads((old / ".lhf_output.json").read_text())
    record_manifest(old, marker["kind"], marker["mutable"])
    _ok(hub_client(fake_hub.endpoint, PUSH_ALL, str(model), repo, str(old), old_repo))

    git_repo = fake_hub.repo_path("models", *repo.split("/"))
    files = set(_git(git_repo, "ls-files").splitlines())
    assert {*MODEL_CODE_FILES, MODEL_EVALS_FILE, "train_config.json", "training_args.json"} <= files
    for name in MODEL_CODE_FILES:
        assert (git_repo / name).read_bytes() == (model / name).read_bytes()
    for needle in (str(tmp_path_factory.getbasetemp()), str(REPO)):
        assert _grep_history(git_repo, needle) == [], needle
    prov = json.loads((git_repo / "train_config.json").read_text())
    assert prov["dataset"]["path"] == f"local:{small_darkroom_batched.root.name}"
    card = (git_repo / "README.md").read_text()
    assert f"lhf evaluate --model {repo} --out ad-no-paths-eval" in card
    assert f"| dataset | a local dataset `{small_darkroom_batched.root.name}`" in card

    old_git = fake_hub.repo_path("models", *old_repo.split("/"))  # the push added the code
    assert json.loads((old_git / "config.json").read_text())["auto_map"] == AUTO_MAP
    for name in MODEL_CODE_FILES:
        assert (old_git / name).read_bytes() == (model / name).read_bytes()
    for config_module, model_module, objective in _last_json(
        _ok(hub_client(olah, TRANSFORMERS_ALONE, repo, old_repo))
    ):
        assert config_module.startswith("transformers_modules.") and objective == "ad"
        assert model_module.startswith("transformers_modules.")


# ---------------------------------------------------------------------------- bad input
@pytest.mark.slow
def test_push_errors(small_darkroom_batched, fake_hub, hub_client, tmp_path):
    ds = str(small_darkroom_batched.root)
    _fails(
        hub_client(fake_hub.endpoint, CLI, "push", ds, "--repo-id", "not a repo"), "invalid repo id"
    )
    (tmp_path / "empty").mkdir()
    _fails(
        hub_client(fake_hub.endpoint, CLI, "push", "empty", "--repo-id", "lhf-test/x"),
        "is not an lhf artifact",
    )
    # No token: the server refuses, the push says where it failed and that nothing was committed,
    # in one line that says the server's reason once and how to log in.
    err = _fails(
        hub_client(
            fake_hub.endpoint, CLI, "push", ds, "--repo-id", "lhf-test/no-token", token=None
        ),
        "failed at 'create the repo'",
        "nothing was committed",
        "(log in with `hf auth login`, set HF_TOKEN, or pass --token)",
    )
    assert err.count("Invalid credentials") == 1 and len(err.strip().splitlines()) == 1, err
    assert not fake_hub.repo_path("datasets", "lhf-test", "no-token").exists()
    # The real Hub without a token: refused before any request (the guard would exit 97).
    _fails(
        hub_client(None, CLI, "push", ds, "--repo-id", "lhf-test/real", token=None),
        "needs a write token",
    )
    # `lhf train --push-to-hub` the same: before any request, and the server's refusal in one line
    train = ["train", "--dataset", ds, "--objective", "ad", "--preset", "tiny", "--max-steps", "2",
             "--batch-size", "4", "--out", "run-no-token"]  # fmt: skip
    err = _fails(hub_client(None, CLI, *train, "--push-to-hub", "lhf-test/real", token=None),
                 "needs a write token")  # fmt: skip
    assert "Traceback" not in err and not (tmp_path / "run-no-token").exists()
    err = _fails(
        hub_client(fake_hub.endpoint, CLI, *train, "--push-to-hub", "lhf-test/t", token=None),
        "--push-to-hub lhf-test/t: the repo could not be created",
        "Invalid credentials",
    )
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    # A commit the server rejects: an error, and the repo keeps its previous state (no tag).
    fake_hub.fail_commits = 1
    _fails(hub_client(fake_hub.endpoint, PUSH, ds, "lhf-test/rejected"), "nothing was committed")
    git_repo = fake_hub.repo_path("datasets", "lhf-test", "rejected")
    assert _git(git_repo, "rev-list", "--count", "main") == "1"  # the Hub's initial commit only
    assert _git(git_repo, "tag") == ""

    # Ctrl-C while the commit request waits: `lhf push` says what the repo may hold (the request
    # may have reached the server); this fake then refuses the commit, so the repo is unchanged.
    pid_file = tmp_path / "client.pid"
    pid_cli = f"import os\nopen({str(pid_file)!r}, 'w').write(str(os.getpid()))\n{CLI}"
    fake_hub.on_commit = lambda: _interrupt_and_wait(int(pid_file.read_text()))
    fake_hub.fail_commits = 1
    try:
        proc = hub_client(fake_hub.endpoint, pid_cli, "push", ds, "--repo-id", "lhf-test/halted")
    finally:
        fake_hub.on_commit, fake_hub.fail_commits = None, 0
    assert proc.returncode == 130, proc.stderr[-2000:]
    assert proc.stderr.strip().splitlines()[-1] == (
        "lhf push: interrupted (interrupted at 'commit': the Hub applies a commit whole, so "
        "lhf-test/halted holds its previous files or all of this push's; run `lhf push` again to "
        "be sure)"
    )
    halted = fake_hub.repo_path("datasets", "lhf-test", "halted")
    assert _git(halted, "rev-list", "--count", "main") == "1"


@pytest.mark.slow
def test_load_errors(fake_hub, olah, hub_client):
    # A dataset repo that is not in our layout: a plain repo with a CSV.
    plain = fake_hub.repo_path("datasets", "lhf-test", "plain-csv")
    plain.mkdir(parents=True)
    (plain / "data.csv").write_text("a,b\n1,2\n")
    (plain / "README.md").write_text("# just a csv\n")
    _git(plain, "init", "-q", "-b", "main")
    _git(plain, "add", "-A")
    _git(plain, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "csv")
    _fails(
        hub_client(olah, CLI, "filter", "lhf-test/plain-csv", "--out", "s"),
        "lhf-test/plain-csv is not a learning-history dataset in the lhf layout",
    )
    _fails(
        hub_client(olah, CLI, "filter", "lhf-test/does-not-exist", "--out", "s"),
        "dataset repo lhf-test/does-not-exist",
        "does not exist",
    )
    _fails(
        hub_client(olah, CLI, "evaluate", "--model", "lhf-test/no-such-model", "--out", "e"),
        "model repo lhf-test/no-such-model",
    )
    _fails(hub_client(olah, CLI, "filter", "no/such/thing", "--out", "s"), "no such local folder")
    # olah answers a missing revision as a missing repo: the repo is asked for again, and named
    _fails(
        hub_client(olah, CLI, "filter", "lhf-test/plain-csv@no-such-rev", "--out", "s"),
        "revision 'no-such-rev' does not exist (it has main)",
    )
    # verify tries a dataset repo, then a model repo: a dataset repo without the revision is
    # the answer, not "no model repo"
    _fails(
        hub_client(olah, CLI, "verify", "lhf-test/plain-csv@no-such-rev"),
        "revision 'no-such-rev' does not exist (it has main)",
    )


def test_repo_ref_parsing():
    from lhf_hf.hub import HubError, HubRef, parse_hub_ref, validate_repo_id

    assert parse_hub_ref("org/name") == HubRef("org/name")
    assert parse_hub_ref("org/name@v3.0") == HubRef("org/name", "v3.0")
    assert parse_hub_ref("./org/name") is None
    assert parse_hub_ref("/abs/path") is None
    assert parse_hub_ref("a/b/c") is None
    assert parse_hub_ref("name") is None
    assert validate_repo_id("lhf/darkroom-v1.2") == "lhf/darkroom-v1.2"
    for bad in ("lhf/a b", "lhf/x@main", "lhf//x", "lhf/--x"):
        with pytest.raises(HubError, match="invalid repo id"):
            validate_repo_id(bad)


def test_upload_file_selection(tmp_path):
    from lhf_hf.hub import upload_files

    for rel in (
        "config.json",
        "model.safetensors",
        "training_args.bin",
        "checkpoint-500/optimizer.pt",
        ".cache/x",
        "meta/info.json",
        "meta/info.json.tmp",
        "_private",
    ):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("x")
    assert upload_files(tmp_path) == ["config.json", "meta/info.json", "model.safetensors"]
    # an artifact inside this one (an evaluation --out MODEL/eval) is its own, never pushed here
    (tmp_path / "eval").mkdir()
    (tmp_path / "eval" / ".lhf_output.json").write_text("{}")
    (tmp_path / "eval" / "eval_results.json").write_text("{}")
    assert upload_files(tmp_path) == ["config.json", "meta/info.json", "model.safetensors"]


@pytest.mark.slow
def test_push_publishes_only_finished_unchanged_artifacts(
    small_darkroom_batched, fake_hub, hub_client, tmp_path
):
    """What the local readers would refuse is not pushed: files edited after the command wrote
    them, an unfinished folder, a folder of unknown origin; a link is never followed out."""
    from lhf_hf.utils.outputs import MARKER

    def copy(name):
        out = tmp_path / name
        shutil.copytree(small_darkroom_batched.root, out)
        return out

    edited = copy("edited")
    stats = edited / "meta" / "stats.json"
    stats.write_text(stats.read_text().replace('"mean"', '"mean" ', 1))
    _fails(hub_client(fake_hub.endpoint, CLI, "push", str(edited), "--repo-id", "lhf-test/e"),
           "meta/stats.json: changed", "not pushed")  # fmt: skip
    unfinished = copy("unfinished")
    (unfinished / MARKER).write_text(json.dumps({"kind": "dataset", "lhf_hf": "0"}))
    _fails(hub_client(fake_hub.endpoint, CLI, "push", str(unfinished), "--repo-id", "lhf-test/u"),
           "unfinished", "not pushed")  # fmt: skip
    unmarked = copy("unmarked")
    (unmarked / MARKER).unlink()
    _fails(hub_client(fake_hub.endpoint, CLI, "push", str(unmarked), "--repo-id", "lhf-test/n"),
           "cannot be verified")  # fmt: skip
    linked = copy("linked")  # a file replaced by a link to the same bytes elsewhere
    outside = tmp_path / "stats-outside.json"
    shutil.copy(linked / "meta" / "stats.json", outside)
    (linked / "meta" / "stats.json").unlink()
    (linked / "meta" / "stats.json").symlink_to(outside)
    _fails(hub_client(fake_hub.endpoint, CLI, "push", str(linked), "--repo-id", "lhf-test/l"),
           "is a symbolic link")  # fmt: skip
    for name in ("e", "u", "n", "l"):
        assert not fake_hub.repo_path("datasets", "lhf-test", name).exists()


@pytest.mark.slow
def test_a_changed_hub_copy_is_refused_at_load_and_by_verify(
    small_darkroom_batched, fake_hub, olah, hub_client, tmp_path
):
    repo = "lhf-test/tampered"
    _ok(hub_client(fake_hub.endpoint, PUSH, str(small_darkroom_batched.root), repo))
    git_repo = fake_hub.repo_path("datasets", *repo.split("/"))
    assert ".lhf_output.json" in _git(git_repo, "ls-files").splitlines()  # the manifest travels
    _ok(hub_client(olah, CLI, "verify", repo))
    # someone edits the Hub copy (a web commit): loads and verify refuse it
    stats = git_repo / "meta" / "stats.json"
    stats.write_text(stats.read_text().replace('"mean"', '"mean" ', 1))
    _git(git_repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-am", "edit")
    _fails(hub_client(olah, CLI, "filter", repo, "--out", "s"),
           "not those `lhf push` uploaded", "meta/stats.json: changed")  # fmt: skip
    _fails(hub_client(olah, CLI, "verify", repo), "meta/stats.json: changed")


@pytest.mark.slow
def test_an_unreachable_hub_is_one_line(small_darkroom_batched, hub_client):
    proc = hub_client("http://127.0.0.1:9", CLI, "push", str(small_darkroom_batched.root),
                      "--repo-id", "lhf-test/unreachable")  # fmt: skip
    err = _fails(proc, "failed at 'create the repo'", "nothing was committed")
    assert "Traceback" not in err
    assert err.count("Connection refused") <= 1, err  # the socket error once, not with its cause
