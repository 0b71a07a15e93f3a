"""Reduced version of benchmarks/equivalence_batched_sb3.py: the batched collector's mean learning
curve lies in the 99% prediction band of SB3's seed-to-seed spread at every block of 5 episodes."""

import numpy as np
import pytest

from lhf_hf.collection.equivalence import Comparison, compare


def test_band_is_a_prediction_interval():
    sb3 = np.array([[1.0] * 10, [2.0] * 10, [3.0] * 10, [2.0] * 10])
    c = Comparison("x", sb3, np.array([[2.0] * 10, [9.0] * 10]), block=5, level=0.99)
    assert c.k == pytest.approx(5.841 * np.sqrt(1.25), rel=1e-3)  # t_{0.995, 3}
    assert c.inside.tolist() == [[True, True], [False, False]]


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:You have specified a mini-batch size")
@pytest.mark.parametrize(
    "env_id, tasks, steps",
    [("darkroom", [10, 30, 50, 70], 300), ("dark-key-to-door", [100, 2000, 4000, 6000], 500)],
)
@pytest.mark.slow
def test_batched_within_sb3_spread(env_id, tasks, steps):
    c = compare(env_id, tasks, histories=16, steps=steps, sb3_seeds=[0, 1, 2, 3], batched_seeds=[0])
    assert c.inside.all(), c.report()
    # and the comparison is not vacuous: learning happened (Darkroom) / the band is finite
    lo, hi = c.band
    assert np.all(np.isfinite(lo)) and np.all(hi > lo)
    if env_id == "darkroom":
        assert c.blocks(c.sb3).mean(0)[-1] > 2 * c.blocks(c.sb3).mean(0)[0]
