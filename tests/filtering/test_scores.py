"""LHF formulas against hand-computed values (paper section 4)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from lhf_hf.filtering import improvement, sampling_probabilities, stability, unified_score
from lhf_hf.filtering.scores import score_arrays


def test_hand_computed():
    r = [0, 2, 1, 3]  # mean 1.5, gap 3, drops [-1]
    assert improvement(r, 4) == pytest.approx((1.5 + 3) / 8)
    assert stability(r, 4) == pytest.approx(1 - 1 / 4)
    assert unified_score(r, 4) == pytest.approx(0.5625 + 0.75)
    assert unified_score(r, 4, lam=2) == pytest.approx(0.5625 + 1.5)
    r = [5, 3, 4, 1]  # mean 3.25, gap 4, drops [-2, -3]
    assert improvement(r, 5) == pytest.approx(7.25 / 10)
    assert stability(r, 5) == pytest.approx(1 - 2.5 / 5)


def test_no_drop_means_stability_one():
    assert stability([1, 2, 2, 3], 3) == 1.0  # the reference code gives NaN here
    assert stability([2], 3) == 1.0
    assert improvement([2], 4) == pytest.approx(0.25)


def test_vectorised_equals_scalar():
    rng = np.random.default_rng(0)
    r = rng.integers(0, 20, (50, 12)).astype(float)
    rmax = rng.uniform(10, 20, 50)
    s = score_arrays(r, rmax, lam=0.7)
    for i in range(50):
        assert s["improvement"][i] == pytest.approx(improvement(r[i], rmax[i]))
        assert s["stability"][i] == pytest.approx(stability(r[i], rmax[i]))
        assert s["score"][i] == pytest.approx(unified_score(r[i], rmax[i], 0.7))


@pytest.mark.parametrize(
    "bad, match", [([], "empty"), ([1, np.nan], "NaN"), ([1, np.inf], "NaN or infinite")]
)
def test_bad_returns(bad, match):
    with pytest.raises(ValueError, match=match):
        improvement(bad, 1)


def test_bad_r_max_and_lambda():
    for r_max in (0, -1, np.nan):
        with pytest.raises(ValueError, match="r_max"):
            stability([1, 2], r_max)
    with pytest.raises(ValueError, match="lambda"):
        unified_score([1, 2], 2, lam=-1)


def test_sampling_hand_computed():
    np.testing.assert_allclose(sampling_probabilities([1.0, 2.0, 3.0]), [0, 0.5, 1])
    # softmax with alpha = 1 of [0, ln 2, ln 4] is [1, 2, 4] / 7 -> min-max [0, 1/3, 1]
    np.testing.assert_allclose(
        sampling_probabilities(np.log([1.0, 2.0, 4.0]), "softmax", alpha=1.0), [0, 1 / 3, 1]
    )
    np.testing.assert_array_equal(
        sampling_probabilities([1.3, 1.3, 1.3]), [1, 1, 1]
    )  # all alike: keep all
    np.testing.assert_array_equal(sampling_probabilities([0.7]), [1])  # one history
    # huge U / tiny alpha does not overflow
    p = sampling_probabilities([1000.0, 1001.0], "softmax", alpha=1e-3)
    np.testing.assert_allclose(p, [0, 1])


@pytest.mark.filterwarnings("error")  # no RuntimeWarning either
def test_softmax_limits_of_the_temperature():
    """A tiny temperature is the argmax (best P = 1, others 0), never NaN; a huge one keeps all."""
    u = np.array([0.2, 0.9, 0.5, 0.9 - 1e-12])
    for alpha in (1e-320, 5e-324, 1e-30):
        np.testing.assert_array_equal(
            sampling_probabilities(u, "softmax", alpha=alpha), [0, 1, 0, 0]
        )
    np.testing.assert_array_equal(sampling_probabilities(u, "softmax", alpha=1e300), [1, 1, 1, 1])
    # between the limits: the closed form exp(U / a) / sum, min-max normalised
    a = 0.125
    e = np.exp(u / a) / np.exp(u / a).sum()
    np.testing.assert_allclose(
        sampling_probabilities(u, "softmax", alpha=a), (e - e.min()) / (e.max() - e.min())
    )


def test_sampling_errors():
    with pytest.raises(ValueError, match="unknown sampling strategy 'cubic'"):
        sampling_probabilities([1, 2], "cubic")
    with pytest.raises(ValueError, match="alpha"):
        sampling_probabilities([1, 2], "softmax", alpha=0)
    with pytest.raises(ValueError, match="NaN"):
        sampling_probabilities([1, np.nan])


@settings(max_examples=60, deadline=None)
@given(
    u=arrays(np.float64, st.integers(2, 30), elements=st.floats(0, 3)),
    strategy=st.sampled_from(["linear", "softmax"]),
    alpha=st.sampled_from([1 / 16, 0.125, 0.5, 1.0]),
)
def test_probability_properties(u, strategy, alpha):
    p = sampling_probabilities(u, strategy, alpha)
    assert np.all((p >= 0) & (p <= 1))
    # Ties are judged after the transform: U values closer than float resolution of exp(U / alpha)
    # are equal for softmax (e.g. 8e-122 vs 0), and then the task is kept unchanged.
    z = u / alpha
    transformed = u if strategy == "linear" else np.exp(z - z.max())
    if transformed.max() > transformed.min():
        assert p[np.argmax(u)] == 1 and p[np.argmin(u)] == 0
        # monotone in U
        order = np.argsort(u, kind="stable")
        assert np.all(np.diff(p[order]) >= -1e-12)
    else:
        assert np.all(p == 1)
