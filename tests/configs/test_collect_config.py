"""CollectConfig validation: bad input fails before any work, with a message naming the field."""

import pytest

from lhf_hf.configs import CollectConfig
from lhf_hf.configs.collect import ppo_preset
from lhf_hf.errors import OutOfRangeError


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(protocol="greedy"), "protocol must be one of"),
        (dict(algo="dqn"), "algo must be one of"),
        (dict(algo="sac"), "needs continuous actions"),
        (dict(steps=30), "multiple of the horizon of darkroom \\(20\\)"),
        (dict(steps=0), "multiple of the horizon"),
        (dict(histories=0), "histories must be >= 1"),
        (dict(tasks="0,81"), "out of range"),
        (dict(tasks="first"), "comma-separated"),
        (dict(tasks=[]), "empty"),
        (dict(noisy_fraction=1.0), "noisy_fraction"),
        (dict(protocol="noisy", histories=1, noisy_fraction=0.9), "no learner histories"),
        (dict(collector="jax"), "collector must be one of"),
        (dict(workers=0), "workers"),
        (dict(device="gpu", collector="batched"), "device must be 'cpu' or 'cuda\\[:N\\]'"),
        (dict(device="cuda", collector="sb3"), "needs collector='batched'"),
        (dict(device="cuda", algo="sac", env_id="metaworld-reach"), "needs collector='batched'"),
    ],
)
def test_rejects(kwargs, match):
    with pytest.raises((ValueError, IndexError), match=match):
        CollectConfig(**{"env_id": "darkroom", **kwargs})


def test_unknown_env():
    with pytest.raises(KeyError, match="valid ids"):
        CollectConfig("darkroom-xl")


def test_tasks_and_presets():
    assert CollectConfig("darkroom", tasks="test").tasks == sorted(
        __import__("lhf_hf.envs", fromlist=["task_split"]).task_split("darkroom", 0)[1]
    )
    assert len(CollectConfig("darkroom", tasks="all").tasks) == 81
    assert len(CollectConfig("darkroom").tasks) == 73  # the train split by default
    assert CollectConfig("darkroom", tasks="7, 3,3").tasks == [3, 7]
    # tuning data: the train tasks without the validation tasks (held out for evaluation)
    assert CollectConfig("darkroom", tasks="validation").tasks == [2, 35, 42, 44, 54, 55, 77, 80]
    fit = CollectConfig("darkroom", tasks="fit").tasks
    assert len(fit) == 65 and not {2, 35, 42, 44, 54, 55, 77, 80} & set(fit)
    assert CollectConfig("darkroom", tasks="fit:3").tasks == fit[:3]
    assert CollectConfig("darkroom", tasks="validation:8").tasks == [2, 35, 42, 44, 54, 55, 77, 80]
    with pytest.raises(
        OutOfRangeError, match="validation part of split 0 has 8 tasks, fewer than 9"
    ):
        CollectConfig("darkroom", tasks="validation:9")  # never clipped silently
    assert (
        ppo_preset("dark-key-to-door").n_epochs == 10
        and ppo_preset("metaworld-push").n_steps == 100
    )
    c = CollectConfig("darkroom", histories=10, protocol="noisy")
    assert c.num_random_histories == 3 and c.episodes_per_history == 50
    assert CollectConfig.from_dict(c.to_dict()) == c
    assert "workers" not in c.identity()


@pytest.mark.parametrize(
    "env_id, algo, collector",
    [
        ("darkroom", "ppo", "batched"),
        ("dark-key-to-door", "ppo", "batched"),
        ("metaworld-reach", "ppo", "sb3"),  # no batched core
        ("metaworld-reach", "sac", "sb3"),  # the batched collector runs PPO only
    ],
)
def test_the_default_collector_is_resolved_per_env_and_recorded(env_id, algo, collector):
    """``auto`` becomes the batched collector where it applies, SB3 elsewhere; the config (and so
    the dataset's recorded config and identity) holds the collector, never ``auto``."""
    c = CollectConfig(env_id, algo=algo, tasks="0")
    assert c.collector == collector
    assert c.to_dict()["collector"] == c.identity()["collector"] == collector
    assert CollectConfig.from_dict(c.to_dict()) == c
    assert CollectConfig(env_id, algo=algo, tasks="0", collector="sb3").collector == "sb3"
    if collector == "sb3":  # the batched collector, asked for where it does not apply: said so
        with pytest.raises(ValueError, match="use collector='sb3'"):
            CollectConfig(env_id, algo=algo, tasks="0", collector="batched")


def test_device_is_part_of_the_identity_unless_default():
    cpu = CollectConfig("darkroom", collector="batched")
    assert cpu.device == "cpu" and "device" not in cpu.identity()  # as before the field existed
    gpu = CollectConfig("darkroom", collector="batched", device="cuda:1")  # no GPU needed here
    assert gpu.identity()["device"] == "cuda:1"
    assert CollectConfig.from_dict(gpu.to_dict()) == gpu
