import os
import tempfile

import pytest

# Headless MuJoCo for every test process (and the subprocesses they start).
os.environ.setdefault("MUJOCO_GL", "disable")
# Keep the tests' Hugging Face caches (datasets' Arrow cache) out of the user's ~/.cache.
os.environ.setdefault("HF_HOME", tempfile.mkdtemp(prefix="lhf-tests-hf-"))

#: A small real collection shared by the histories/collection tests: 3 Darkroom tasks, 10 histories
#: of 200 transitions, noisy protocol (7 PPO + 3 random histories per task).
SMALL = dict(
    env_id="darkroom",
    tasks="3,40,62",
    histories=10,
    steps=200,
    protocol="noisy",
    seed=0,
    workers=1,
    collector="sb3",
)


@pytest.fixture(scope="session")
def small_darkroom(tmp_path_factory):
    from lhf_hf.collection import collect
    from lhf_hf.configs import CollectConfig

    root = tmp_path_factory.mktemp("small") / "darkroom"
    return collect(CollectConfig(**SMALL), root, progress=False)


@pytest.fixture(scope="session")
def small_darkroom_batched(tmp_path_factory):
    from lhf_hf.collection import collect
    from lhf_hf.configs import CollectConfig

    root = tmp_path_factory.mktemp("small") / "darkroom-batched"
    return collect(CollectConfig(**{**SMALL, "collector": "batched"}), root, progress=False)


@pytest.fixture(params=["sb3", "batched"])
def collected(request):
    """The small collection made by each collector (invariants must hold for both)."""
    return request.getfixturevalue(
        "small_darkroom" if request.param == "sb3" else "small_darkroom_batched"
    )


@pytest.fixture(scope="session")
def learned_darkroom(tmp_path_factory):
    """2 Darkroom tasks x 4 histories x 1,000 steps (batched PPO): the late actions are predictable,
    so the action losses of AD / DICP can fall well below the uniform log 5."""
    from lhf_hf.collection import collect
    from lhf_hf.configs import CollectConfig

    root = tmp_path_factory.mktemp("learned") / "darkroom"
    cfg = CollectConfig(
        env_id="darkroom", tasks="3,40", histories=4, steps=1000, collector="batched", seed=0
    )
    return collect(cfg, root, progress=False)


@pytest.fixture
def handlers():
    """The test process's SIGINT/SIGTERM handlers, put back afterwards (tests that send signals)."""
    import signal

    held = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    yield held
    for sig, handler in held.items():
        signal.signal(sig, handler)


@pytest.fixture(scope="session")
def tiny_model(small_darkroom_batched, tmp_path_factory):
    """A tiny DICP trained by ``lhf train`` (4 steps, a checkpoint every 2) with band attention
    over 8 transitions, so that evaluating it (the streaming cache) takes seconds: the checkpoint
    whose card, code and transformers-only loading the tests check."""
    from lhf_hf.configs import TrainConfig
    from lhf_hf.training import train

    out = tmp_path_factory.mktemp("tiny-model") / "dicp"
    cfg = TrainConfig(dataset=str(small_darkroom_batched.root), objective="dicp", out=str(out),
                      preset="tiny", context_length=8, attention="band", sequence_length=16,
                      batch_size=4, max_steps=4, save_steps=2, logging_steps=2)  # fmt: skip
    return train(cfg, progress=False)
