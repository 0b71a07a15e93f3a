"""Algorithm 1 and lhf_resample on histories tables (hypothesis properties)."""

import datasets
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lhf_hf.filtering import algorithm1, lhf_resample
from lhf_hf.filtering.resample import task_rng, top_fraction_counts
from lhf_hf.filtering.scores import score_arrays


def table(returns_per_task: dict[int, np.ndarray]) -> datasets.Dataset:
    rows = {"task_id": [], "history_index": [], "returns": []}
    h = 0
    for task, r in returns_per_task.items():
        for row in r:
            rows["task_id"].append(task)
            rows["history_index"].append(h)
            rows["returns"].append(row.tolist())
            h += 1
    return datasets.Dataset.from_dict(rows)


def test_algorithm1_extremes():
    rng = np.random.default_rng(0)
    order = np.arange(4)
    np.testing.assert_array_equal(algorithm1(np.array([1.0, 0, 0, 0]), order, rng), [4, 0, 0, 0])
    np.testing.assert_array_equal(
        algorithm1(np.ones(4), order, rng), [1, 1, 1, 1]
    )  # one pass keeps all
    with pytest.raises(ValueError, match="never finish"):
        algorithm1(np.zeros(3), np.arange(3), rng)


def test_algorithm1_frequencies_follow_probabilities():
    # Expected counts are proportional to P (each pass accepts l with prob P_l).
    p = np.array([1.0, 0.5, 0.25, 0.0])
    total = np.zeros(4)
    for s in range(400):
        total += algorithm1(p, np.argsort(-p), task_rng(s, 0), target=40)
    share = total / total.sum()
    np.testing.assert_allclose(share, p / p.sum(), atol=0.01)


def test_top_fraction_counts():
    np.testing.assert_array_equal(
        top_fraction_counts(np.array([0.1, 0.9, 0.5, 0.3]), 0.5), [0, 2, 2, 0]
    )
    np.testing.assert_array_equal(top_fraction_counts(np.array([0.1, 0.9, 0.5]), 0.5), [0, 2, 1])


returns_strategy = st.integers(1, 6).flatmap(
    lambda n_tasks: st.lists(
        st.tuples(st.integers(1, 12), st.integers(1, 8), st.integers(0, 10_000)),
        min_size=n_tasks,
        max_size=n_tasks,
    )
)


@settings(max_examples=40, deadline=None)
@given(
    spec=returns_strategy,
    strategy=st.sampled_from(["linear", "softmax"]),
    lam=st.sampled_from([0.0, 0.5, 1.0, 2.0]),
    seed=st.integers(0, 3),
)
@pytest.mark.slow
def test_resample_properties(spec, strategy, lam, seed):
    returns = {
        t: np.random.default_rng(s).integers(0, 20, (n, e)).astype(float)
        for t, (n, e, s) in enumerate(spec)
    }
    ds = table(returns)
    sel = lhf_resample(ds, lam=lam, strategy=strategy, seed=seed, r_max=20.0).to_pandas()
    again = lhf_resample(ds, lam=lam, strategy=strategy, seed=seed, r_max=20.0).to_pandas()
    assert sel.equals(again)  # same seed, same selection
    for t, r in returns.items():
        rows = sel[sel.task_id == t]
        assert rows["count"].sum() == len(r)  # the task keeps its size
        assert (rows["probability"] > 0).all()  # P = 0 is never selected
        u = score_arrays(r, 20.0, lam)["score"]
        if u.max() > u.min():
            best = int(np.argmax(u))
            first = int(ds.filter(lambda x, t=t: x["task_id"] == t)["history_index"][0])
            assert first + best in rows["history_index"].tolist()  # the best (P = 1) is always kept
        else:
            assert (rows["count"] == 1).all() and len(rows) == len(r)  # all alike: unchanged


def test_lambda_zero_ranks_by_improvement():
    rng = np.random.default_rng(3)
    r = rng.integers(0, 20, (30, 10)).astype(float)
    sel = lhf_resample(table({0: r}), lam=0.0, r_max=20.0, seed=0).to_pandas()
    s = score_arrays(r, 20.0, 0.0)
    np.testing.assert_allclose(sel["score"], s["improvement"][sel["history_index"]])
    p = (s["improvement"] - s["improvement"].min()) / np.ptp(s["improvement"])
    np.testing.assert_allclose(sel["probability"], p[sel["history_index"]])


def test_ablations():
    r = np.random.default_rng(0).integers(0, 20, (10, 6)).astype(float)
    none = lhf_resample(table({0: r}), strategy="none", r_max=20.0).to_pandas()
    assert none["count"].tolist() == [1] * 10
    top = lhf_resample(table({0: r}), strategy="top-fraction", fraction=0.3, r_max=20.0).to_pandas()
    assert len(top) == 3 and top["count"].sum() == 10
    u = score_arrays(r, 20.0)["score"]
    assert sorted(top["history_index"]) == sorted(np.argsort(-u, kind="stable")[:3].tolist())


def test_single_history_task_unchanged():
    sel = lhf_resample(
        table({0: np.array([[1.0, 2.0]]), 1: np.array([[0, 1], [1, 1], [3, 0.0]])}), r_max=3.0
    )
    assert sel.to_pandas().query("task_id == 0")["count"].tolist() == [1]


@pytest.mark.parametrize(
    "returns, kwargs, match",
    [
        ([[1.0, np.nan]], {}, "history 0: returns contain NaN"),
        ([[]], {}, "history 0: empty list"),
        ([[1.0, 2.0]], {"r_max": 0.0}, "r_max"),
        ([[1.0, 2.0]], {"alpha": 0.0, "strategy": "softmax"}, "alpha"),
        ([[1.0, 2.0]], {"strategy": "greedy"}, "strategy"),
        ([[1.0, 2.0]], {"r_max": None}, "r_max is needed"),
    ],
)
def test_errors_name_the_problem(returns, kwargs, match):
    ds = datasets.Dataset.from_dict(
        {
            "task_id": [0] * len(returns),
            "history_index": list(range(len(returns))),
            "returns": returns,
        },
        features=datasets.Features(
            {
                "task_id": datasets.Value("int64"),
                "history_index": datasets.Value("int64"),
                "returns": datasets.List(datasets.Value("float64")),
            }
        ),
    )
    with pytest.raises(ValueError, match=match):
        lhf_resample(ds, **{"r_max": 2.0, **kwargs})


def test_missing_columns():
    with pytest.raises(ValueError, match="lacks the columns"):
        lhf_resample(datasets.Dataset.from_dict({"task_id": [0], "history_index": [0]}), r_max=1.0)


def test_meta_world_needs_r_max():
    ds = table({0: np.ones((2, 3))})
    with pytest.raises(ValueError, match="no known optimal return"):
        lhf_resample(ds, env_id="metaworld-reach")
    lhf_resample(ds, env_id="darkroom")  # gridworld optimal returns are known
