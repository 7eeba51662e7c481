"""The success rate's interval by world: flights that share a world are not independent
trials (minid3rqn/rl/evaluate.py, module docstring); pooling evaluations by world and
pairing two policies on the same worlds (minid3rqn/rl/pool.py)."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from minid3rqn.rl.evaluate import by_world, clustered_interval, evaluate_policy, wilson_interval
from minid3rqn.rl.pool import against_conditions, paired_difference, pool_records, read_records
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


def test_by_world_groups_flights_by_their_world():
    """Flights grouped by world seed, in seed order; the interval is clustered_interval's
    of the counts; one world gives no interval (NaN), and bad shapes are named."""
    success = np.array([1, 0, 1, 1, 1, 0, 1], bool)
    seeds = np.array([30, 10, 30, 20, 10, 10, 20])
    w = by_world(success, seeds)
    assert w.seeds.tolist() == [10, 20, 30]
    assert w.flights.tolist() == [3, 2, 2] and w.successes.tolist() == [1, 2, 2]
    assert (w.ci_low, w.ci_high, w.design_effect) == clustered_interval([1, 2, 2], [3, 2, 2])
    one = by_world(success, np.full(7, 5))
    assert one.flights.tolist() == [7] and np.isnan(one.ci_low)
    with pytest.raises(ValueError, match="world_seed"):
        by_world(success, seeds[:3])


def test_one_world_gives_no_interval_by_world_and_strict_json():
    """A single flight flies one world: no interval by world (NaN in the result, None in
    its dict), and the dict is strict JSON (no NaN token)."""
    import json
    res = evaluate_policy(ReactivePolicy(ACTIONS), "basic", n_flights=1, max_steps=2,
                          progress=False)
    assert res.worlds == 1 and np.isnan(res.ci_low_worlds) and "by world" not in res.line()
    d = res.to_dict()
    assert d["ci_low_worlds"] is None and d["design_effect"] is None
    assert json.loads(json.dumps(d, allow_nan=False)) == d


def test_the_tables_show_both_intervals():
    """reproduce's tables give each row its interval by flight and by world; a record
    written before the interval by world existed leaves that cell blank, not an error."""
    from minid3rqn.rl.reproduce import markdown_tables
    new = {"policy": "d3rqn", "scenario": "basic", "rate": 0.9, "ci_low": 0.88,
           "ci_high": 0.92, "ci_low_worlds": 0.85, "ci_high_worlds": 0.94}
    old = {k: v for k, v in new.items() if "worlds" not in k} | {"policy": "random"}
    table = markdown_tables({"table5": [new, old]}).splitlines()
    assert "| model | ours | 95% CI by flight | by world | paper |" in table
    [row_new] = [r for r in table if r.startswith("| d3rqn")]
    [row_old] = [r for r in table if r.startswith("| random")]
    assert "[0.880, 0.920] | [0.850, 0.940]" in row_new
    assert "[0.880, 0.920] |  |" in row_old


# -- pooling evaluate --json records (minid3rqn/rl/pool.py) --------------------------------
def record(spec, seeds, successes, flights, scenario="intersections", seed=1):
    return {"spec": spec, "policy": spec, "scenario": scenario, "seed": seed,
            "world_seeds": list(seeds), "world_successes": list(successes),
            "world_flights": list(flights), "rate": sum(successes) / max(sum(flights), 1),
            "successes": sum(successes), "flights": sum(flights)}


def test_nets_on_the_same_worlds_pool_per_world():
    """Two nets flown on the same worlds: the worlds count once, with both nets' flights;
    the same counts on different worlds make twice the worlds and a narrower interval."""
    a = record("a", [10, 11, 12], [5, 9, 10], [10, 10, 10])
    b = record("b", [10, 11, 12], [4, 9, 10], [10, 10, 10])
    same = pool_records([a, b])
    assert (same.worlds, same.flights, same.successes) == (3, 60, 47)
    c = record("b", [20, 21, 22], [4, 9, 10], [10, 10, 10], seed=2)
    apart = pool_records([a, c])
    assert apart.worlds == 6 and apart.successes == same.successes
    assert apart.ci_high_worlds - apart.ci_low_worlds < same.ci_high_worlds - same.ci_low_worlds
    other = record("b", [10, 11, 12], [4, 9, 10], [10, 10, 10], scenario="corners")
    assert pool_records([a, other]).worlds == 6      # another scenario: other worlds


def test_paired_difference_removes_what_the_worlds_share():
    """B fails one more flight than A in every world: the paired difference is exact (zero
    width); A against itself is 0; unpaired worlds are refused with a named error."""
    seeds, m = range(8), [10] * 8
    ya = [10, 9, 3, 10, 6, 10, 8, 2]                  # worlds differ a lot
    a = record("a", seeds, ya, m)
    b = record("b", seeds, [y - 1 for y in ya], m)
    d, lo, hi, c = paired_difference([a], [b])
    assert c == 8 and d == pytest.approx(0.1) and hi - lo == pytest.approx(0.0, abs=1e-12)
    assert paired_difference([a], [a])[:3] == pytest.approx((0.0, 0.0, 0.0))
    apart = record("b", range(8, 16), ya, m)
    with pytest.raises(ValueError, match="different worlds"):
        paired_difference([a], [apart])


def test_records_without_world_counts_and_bad_files_are_named(tmp_path):
    old = record("old", [], [], [])
    with pytest.raises(ValueError, match="no world counts"):
        pool_records([old])
    with pytest.raises(ValueError, match="no evaluation records"):
        pool_records([])
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"scenario": "basic", "seed": 1}\nnot json\n')
    with pytest.raises(ValueError, match="line 2 is not a JSON record"):
        read_records([bad])
    with pytest.raises(FileNotFoundError, match="no such results file"):
        read_records([tmp_path / "missing.jsonl"])


def test_against_keeps_the_where_conditions_it_does_not_name():
    assert against_conditions(["scenario=corners", "spec=runs/*"], ["spec=reactive"]) == \
        ["scenario=corners", "spec=reactive"]


def test_where_takes_a_pattern_or_any_of_several_values():
    from minid3rqn.rl.pool import _matches
    r = {"seed": 24680, "spec": "runs/nets/seed7_s7/model.npz"}
    assert _matches(r, ["seed=24680", "spec=runs/nets/*"])
    assert _matches(r, ["seed=12345,24680,31415"]) and not _matches(r, ["seed=12345,31415"])
    assert _matches(r, ["spec=minid3rqn/*,runs/ne*"]) and not _matches(r, ["seed=2468"])
    assert not _matches(r, ["scenario=basic"])            # a key the record lacks


def test_pool_command_end_to_end(tmp_path, capsys):
    """evaluate --json, then pool: the pooled counts are the evaluations' own."""
    from minid3rqn.cli import main
    out = tmp_path / "r.jsonl"
    for seed in ("1", "2"):
        assert main(["evaluate", "reactive", "straight", "--scenario", "basic", "--flights",
                     "12", "--chunk", "6", "--steps", "6", "--seed", seed,
                     "--json", str(out)]) == 0
    capsys.readouterr()
    assert main(["pool", str(out), "--where", "spec=reactive", "--against",
                 "spec=straight"]) == 0
    text = capsys.readouterr().out
    rows = [r for r in read_records([out]) if r["spec"] == "reactive"]
    k = sum(r["successes"] for r in rows)
    assert f"({k}/24, 2 evaluations" in text and "paired by world" in text
    assert main(["pool", str(out), "--where", "spec"]) == 2
    assert "--where: expected KEY=VALUE" in capsys.readouterr().err
    assert main(["pool", str(out), "--where", "seed=1", "--against", "seed=2"]) == 2
    assert "different worlds" in capsys.readouterr().err
