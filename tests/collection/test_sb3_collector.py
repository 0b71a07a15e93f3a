"""The SB3 collector: protocols, determinism, learning, Meta-World PPO/SAC."""

import numpy as np
import pytest

from lhf_hf import constants as C
from lhf_hf.collection import collect, collect_task_histories, plan_task
from lhf_hf.configs import CollectConfig


def test_plans_per_protocol():
    paper = plan_task(CollectConfig("darkroom", tasks="0", histories=10, steps=20), 0)
    assert [(p.kind, p.n_streams) for p in paper] == [("ppo", 10)]
    noisy = plan_task(
        CollectConfig("darkroom", tasks="0", histories=10, steps=20, protocol="noisy"), 0
    )
    assert [(p.kind, p.n_streams) for p in noisy] == [("ppo", 7), ("random", 3)]
    indep = plan_task(
        CollectConfig("darkroom", tasks="0", histories=4, steps=20, protocol="independent"), 0
    )
    assert [p.n_streams for p in indep] == [1, 1, 1, 1] and len({p.seed for p in indep}) == 4
    k = plan_task(
        CollectConfig(
            "darkroom", tasks="0", histories=6, steps=20, protocol="learners", learners=3
        ),
        0,
    )
    assert [(p.kind, p.n_streams, p.learner_index) for p in k] == [
        ("ppo", 2, 0),
        ("ppo", 2, 1),
        ("ppo", 2, 2),
    ]
    assert [p.seed for p in k] == [p.seed for p in indep[:3]]  # the task's seeds, in order
    # seeds depend on (seed, task) only
    assert plan_task(CollectConfig("darkroom", tasks="0,5", histories=4, steps=20), 5) == plan_task(
        CollectConfig("darkroom", tasks="5", histories=4, steps=20), 5
    )


@pytest.mark.slow
def test_independent_learners_differ():
    th = collect_task_histories(
        CollectConfig(
            "darkroom", tasks="40", histories=3, steps=100, protocol="independent", workers=1
        ),
        40,
    )
    assert th.learner == ["ppo"] * 3 and len(set(th.seeds.tolist())) == 3
    assert not np.array_equal(th.actions[0], th.actions[1])


@pytest.mark.slow
def test_same_seed_same_data(tmp_path):
    cfg = dict(env_id="darkroom", tasks="12", histories=4, steps=100, protocol="noisy", workers=1,
               collector="sb3")  # fmt: skip
    a = collect(CollectConfig(**cfg), tmp_path / "a", progress=False)
    b = collect(CollectConfig(**cfg), tmp_path / "b", progress=False)
    assert a.fingerprint == b.fingerprint
    assert a.frame_table().equals(b.frame_table())
    c = collect(CollectConfig(**{**cfg, "seed": 1}), tmp_path / "c", progress=False)
    assert c.fingerprint != a.fingerprint


@pytest.mark.slow
def test_ppo_histories_improve_on_darkroom(tmp_path):
    # Paper protocol, 16 copies per learner, 25 episodes: late episodes must beat early ones clearly.
    ds = collect(
        CollectConfig(
            "darkroom", tasks="30,50", histories=16, steps=500, workers=2, collector="sb3"
        ),
        tmp_path / "d",
        progress=False,
    )
    returns = np.asarray(ds.histories.data.column(C.RETURNS).to_pylist())  # (32, 25)
    early, late = returns[:, :5].mean(), returns[:, -5:].mean()
    assert late > early + 4 and late > 2 * early, (early, late)


@pytest.mark.slow
@pytest.mark.metaworld
@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_metaworld_collection(tmp_path, algo):
    pytest.importorskip("metaworld")
    cfg = CollectConfig(
        "metaworld-reach",
        tasks="0",
        histories=2,
        steps=200,
        algo=algo,
        workers=1,
        sac={"learning_starts": 100, "batch_size": 32},
    )
    ds = collect(cfg, tmp_path / algo, progress=False)
    t = ds.frame_table()
    act = np.stack(t.column(C.ACTION).to_numpy(zero_copy_only=False))
    assert act.shape == (400, 4) and act.dtype == np.float32 and np.all(np.abs(act) <= 1)
    obs = np.stack(t.column(C.OBS).to_numpy(zero_copy_only=False))
    nxt = np.stack(t.column(C.NEXT_OBS).to_numpy(zero_copy_only=False))
    done = t.column(C.DONE).to_numpy()
    assert obs.shape == (400, 39) and np.all(obs[:, -3:] == 0)
    np.testing.assert_array_equal(nxt[:-1][~done[:-1]], obs[1:][~done[:-1]])
    assert C.SUCCESS in t.column_names and C.OPTIMAL_ACTION not in t.column_names
    ep = ds.episodes.to_pandas()
    assert len(ep) == 4 and C.EPISODE_SUCCESS in ep
    assert ds.histories.to_pandas()[C.LEARNER].tolist() == [algo, algo]
    assert ds.info["features"][C.ACTION] == {"dtype": "float32", "shape": [4], "names": None}
    assert "metaworld" in ds.lhf["versions"]
