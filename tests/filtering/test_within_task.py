"""The within-task comparison of kept and rejected histories, on a hand-made Simpson's paradox."""

import numpy as np
import pytest

from lhf_hf.filtering.within_task import describe, sign_test, within_task


def test_kept_lower_pooled_but_higher_in_every_task():
    # task 0: the learner barely learned (returns ~1); task 1: it learned (returns ~10-12);
    # task 2: everything kept (not compared)
    task = np.array([0] * 6 + [1] * 6 + [2] * 2)
    ret = np.array([1, 1, 1, 1, 1, 0] + [10, 10, 10, 10, 10, 12] + [3, 3], dtype=float)
    count = np.array([1, 1, 1, 1, 2, 0] + [0, 0, 0, 0, 0, 6] + [1, 1])
    kept, rejected = ret[:12][count[:12] > 0], ret[:12][count[:12] == 0]
    assert kept.mean() == pytest.approx(17 / 6) and rejected.mean() == pytest.approx(50 / 6)
    w = within_task(task, ret, count)
    assert w["tasks"] == 3 and w["tasks_compared"] == 2
    assert w["kept_minus_rejected"] == pytest.approx((1 + 2) / 2)  # +1 in task 0, +2 in task 1
    assert (w["tasks_kept_higher"], w["tasks_kept_lower"], w["tasks_tied"]) == (2, 0, 0)
    assert w["sign_test_p"] == pytest.approx(0.5)
    # count-weighted minus plain mean, per task: 1 - 5/6, 12 - 62/6, 0
    assert w["selection_minus_source"] == pytest.approx((1 / 6 + 5 / 3 + 0) / 3)
    assert (
        w["tasks_never_reached"] == 0
        and w["kept_minus_rejected_reached"] == w["kept_minus_rejected"]
    )
    # spread of history means within each task (sample std), averaged: task 0 [1,1,1,1,1,0],
    # task 1 [10 x 5, 12], task 2 [3, 3]
    assert w["history_spread"] == pytest.approx(
        (np.std([1] * 5 + [0], ddof=1) + np.std([10] * 5 + [12], ddof=1)) / 3
    )


def test_tasks_that_never_reached_the_goal_are_told_apart():
    """A task whose histories all return 0 ties whatever is kept: counted apart, and the
    difference over the tasks that reached the goal is reported beside the pooled one."""
    task = np.array([0, 0, 0, 1, 1, 1])
    ret = np.array([0.0, 0.0, 0.0, 4.0, 6.0, 2.0])
    count = np.array([2, 1, 0, 1, 2, 0])
    w = within_task(task, ret, count)
    assert w["tasks_compared"] == 2 and w["tasks_never_reached"] == 1
    assert w["kept_minus_rejected"] == pytest.approx((0 + (5 - 2)) / 2)
    assert w["kept_minus_rejected_reached"] == pytest.approx(3.0)
    assert "1 of them never reached the goal (all returns 0), the others +3.000" in describe(
        w, long=True
    )


def test_sign_test_is_the_exact_binomial():
    assert sign_test(7, 1) == pytest.approx(2 * (1 + 8) / 256)
    assert sign_test(4, 4) == 1.0 and sign_test(0, 0) == 1.0
    assert sign_test(0, 10) == pytest.approx(2 / 1024)


def test_ties_are_counted_apart():
    task = np.array([0, 0, 1, 1])
    w = within_task(task, np.array([2.0, 2.0, 5.0, 1.0]), np.array([1, 0, 0, 2]))
    assert (w["tasks_kept_higher"], w["tasks_kept_lower"], w["tasks_tied"]) == (0, 1, 1)
    assert w["kept_minus_rejected"] == pytest.approx((0 - 4) / 2)
