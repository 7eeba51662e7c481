"""The success rate's interval by world: flights that share a world are not independent
trials (minid3rqn/rl/evaluate.py, module docstring)."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from minid3rqn.rl.evaluate import clustered_interval, evaluate_policy, wilson_interval
from minid3rqn.rl.policies import ReactivePolicy
from minid3rqn.world import ACTIONS

pytestmark = pytest.mark.rl


def contains(outer, inner, tol=1e-12) -> bool:
    return outer[0] <= inner[0] + tol and inner[1] <= outer[1] + tol


def test_one_flight_per_world_is_wilsons_interval():
    """Nothing is shared when every flight has its own world: deff = C / (C - 1)."""
    rng = np.random.default_rng(0)
    y = (rng.random(400) < 0.8).astype(np.int64)
    lo, hi, deff = clustered_interval(y, np.ones(400, np.int64))
    assert deff == pytest.approx(400 / 399)
    w = wilson_interval(int(y.sum()), 400)
    assert lo == pytest.approx(w[0], abs=2e-4) and hi == pytest.approx(w[1], abs=2e-4)


def test_worlds_alike_never_narrow_the_interval():
    """Every world with the same successes: no variance between worlds (deff 0), and the
    interval stays Wilson's by flight (deff is taken as at least 1)."""
    lo, hi, deff = clustered_interval(np.full(50, 9), np.full(50, 10))
    assert deff == 0.0
    assert (lo, hi) == wilson_interval(450, 500)


def test_all_or_nothing_worlds_count_as_one_trial_each():
    """Worlds that pass or fail all their m flights: deff = C m / (C - 1), and the interval
    is as wide as Wilson's over the C worlds (slightly wider: C - 1 effective trials)."""
    c, m = 40, 16
    y = np.where(np.arange(c) < 30, m, 0)
    lo, hi, deff = clustered_interval(y, np.full(c, m))
    assert deff == pytest.approx(c * m / (c - 1))
    by_world = wilson_interval(30, c)
    assert contains((lo, hi), by_world)
    assert hi - lo == pytest.approx(by_world[1] - by_world[0], rel=0.05)
    assert contains((lo, hi), wilson_interval(30 * m, c * m))


def test_all_successes_and_all_failures():
    for k in (0, 1):
        lo, hi, deff = clustered_interval(np.full(8, 5 * k), np.full(8, 5))
        assert deff == 1.0 and (lo, hi) == wilson_interval(40 * k, 40)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 30), st.floats(0, 1)), min_size=2, max_size=60))
def test_the_interval_by_world_holds_the_rate_and_wilsons_interval(worlds):
    m = np.array([f for f, _ in worlds], np.int64)
    y = np.array([round(f * q) for f, q in worlds], np.int64)
    lo, hi, deff = clustered_interval(y, m)
    p = y.sum() / m.sum()
    assert 0.0 <= lo <= p <= hi <= 1.0 and deff >= 0.0
    assert contains((lo, hi), wilson_interval(int(y.sum()), int(m.sum())))


@pytest.mark.parametrize("y, m, words", [
    ([1, 2], [3], "one entry per world"),
    ([1], [3], "at least 2 worlds"),
    ([4, 1], [3, 3], "0 <= world_successes <= world_flights"),
    ([1, 1], [0, 3], "world_flights >= 1"),
    ([0.5, 1.0], [3, 3], "world_successes must be a 1-D array of integers"),
    ([[1, 1]], [[3, 3]], "world_successes must be a 1-D array of integers"),
])
def test_bad_counts_are_named(y, m, words):
    with pytest.raises(ValueError, match="clustered_interval") as e:
        clustered_interval(np.array(y), np.array(m))
    assert words in str(e.value)


def test_an_evaluation_reports_its_worlds():
    """Each chunk flies a pool of its own: 24 flights in chunks of 8 with pools of up to
    8 worlds; the per-world counts add up to the flights and successes, the interval by
    world holds the one by flight, and two workers give the same counts."""
    one = evaluate_policy(ReactivePolicy(ACTIONS), "basic", n_flights=24, chunk=8,
                          max_steps=8, progress=False)
    assert one.worlds == len(one.world_flights) == len(one.world_successes) > 8
    assert sum(one.world_flights) == 24 and sum(one.world_successes) == one.successes
    assert contains((one.ci_low_worlds, one.ci_high_worlds), (one.ci_low, one.ci_high))
    assert "by world" in one.line() and f"{one.worlds} worlds" in one.line()
    two = evaluate_policy(ReactivePolicy(ACTIONS), "basic", n_flights=24, chunk=8,
                          max_steps=8, progress=False, workers=2)
    assert (two.world_successes, two.world_flights) == (one.world_successes, one.world_flights)
    assert one.to_dict()["design_effect"] == pytest.approx(two.design_effect)
