"""Pool evaluations by world, and compare two policies on the same worlds (ours).

``evaluate --json FILE`` appends one record per policy flown: its rate, Wilson's
interval by flight, and each world's seed, successes and flights (``rl/evaluate.py``).
This module reads such records back and answers two questions a single evaluation
cannot:

1. **Several evaluations together.** Six nets of one recipe, or one net on three sets of
   test worlds: what is the rate, and how sure are we? Flights are summed per *world*
   (a world is its scenario and its seed: six nets flown with
   the same evaluation seed fly the same 128 worlds, so those worlds count once, with six
   times the flights), and the interval is the by-world one of
   ``evaluate.clustered_interval``. Summing the flights and taking Wilson's interval
   would count six nets in one world as if they were six worlds.

2. **A against B on the same worlds** (``--against``): the difference of their rates,
   paired by world. For two ratio means over the same C worlds, p_A = sum y_A / M_A and
   p_B = sum y_B / M_B (y a world's successes, m its flights, M the sum of m), the
   linearised (Taylor) variance of p_A - p_B is

       var = C / (C - 1) * sum_c z_c^2,
       z_c = (y_A,c - p_A m_A,c) / M_A - (y_B,c - p_B m_B,c) / M_B

   and the 95% interval is p_A - p_B +- 1.96 sqrt(var). A world that is hard for both
   costs both, so the pairing takes the luck of which worlds were drawn out of the
   comparison; two intervals side by side keep it in twice.

    python -m minid3rqn pool runs/eval.jsonl --where scenario=intersections \\
        --where 'spec=runs/e37_twin/*' --against spec=reactive

``--against`` keeps the ``--where`` conditions it does not name: above, the reactive rule
in intersections.

3. **Do these groups differ, or is it the luck of the worlds?** (``--split KEY``, e.g.
   ``--split seed``: one net on three sets of test worlds.) Each group's rate p_g with
   its variance v_g (by flight p (1 - p) / n; by world var_w of ``clustered_interval``,
   never below the by-flight one), and the test of equal rates

       p_bar = sum_g (p_g / v_g) / sum_g (1 / v_g),   X^2 = sum_g (p_g - p_bar)^2 / v_g

   against the chi-square distribution with G - 1 degrees of freedom (``chi2_sf``). The
   groups must fly different worlds (a stray world drawn by two evaluation seeds is
   let pass); groups that share more than 5% of their worlds are a paired question
   (``--against``).
"""
from __future__ import annotations

import argparse
import fnmatch
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import UsageError
from .evaluate import clustered_interval, wilson_interval, world_variance


@dataclass
class Pooled:
    records: int
    flights: int
    successes: int
    rate: float
    ci_low: float             # Wilson, flights as independent trials
    ci_high: float
    worlds: int
    ci_low_worlds: float      # by world (evaluate.clustered_interval)
    ci_high_worlds: float
    design_effect: float

    def line(self, name: str = "pooled") -> str:
        evaluations = f"{self.records} evaluation" + ("s" if self.records != 1 else "")
        return (f"{name}: {self.rate:.4f} ({self.successes}/{self.flights}, {evaluations}, "
                f"{self.worlds} worlds); by flight [{self.ci_low:.4f}, "
                f"{self.ci_high:.4f}]; by world [{self.ci_low_worlds:.4f}, "
                f"{self.ci_high_worlds:.4f}], deff {self.design_effect:.2f}")


def world_key(record: dict, seed: int) -> tuple:
    """What names a world: its scenario and its seed."""
    return record["scenario"], int(seed)


def world_counts(records: list[dict]) -> dict:
    """{world key: [successes, flights]} summed over ``records``."""
    counts: dict = {}
    for i, r in enumerate(records):
        seeds = r.get("world_seeds")
        if not seeds:
            raise ValueError(f"pool: record {i} ({r.get('spec', r.get('policy'))}, "
                             f"{r.get('scenario')}, seed {r.get('seed')}) has no world counts; "
                             f"it was written before evaluate recorded them: fly it again")
        for s, y, m in zip(seeds, r["world_successes"], r["world_flights"]):
            c = counts.setdefault(world_key(r, s), [0, 0])
            c[0] += int(y)
            c[1] += int(m)
    return counts


def pool_records(records: list[dict]) -> Pooled:
    """The rate over all flights of ``records``, with both intervals."""
    if not records:
        raise ValueError("pool: no evaluation records to pool (check --where)")
    counts = np.array(list(world_counts(records).values()), dtype=np.int64)   # (C, 2)
    k, n = int(counts[:, 0].sum()), int(counts[:, 1].sum())
    lo, hi = wilson_interval(k, n)
    if len(counts) >= 2:
        w_lo, w_hi, deff = clustered_interval(counts[:, 0], counts[:, 1])
    else:
        w_lo = w_hi = deff = float("nan")
    return Pooled(len(records), n, k, k / n, lo, hi, len(counts), w_lo, w_hi, deff)


def chi2_sf(x: float, df: int) -> float:
    """P(X >= x) for X chi-square with ``df`` degrees of freedom: 1 - P(df/2, x/2), the
    regularized lower incomplete gamma function by its power series

        P(a, t) = t^a e^-t / Gamma(a) * sum_k t^k / (a (a + 1) ... (a + k)),

    which converges for every t (here t stays small: tens at most)."""
    if df < 1:
        raise ValueError(f"chi2_sf: df must be >= 1; got {df}")
    if x <= 0:
        return 1.0
    a, t = df / 2.0, x / 2.0
    term = total = 1.0 / a
    k = 0
    while term > 1e-17 * total:
        k += 1
        term *= t / (a + k)
        total += term
    lower = math.exp(a * math.log(t) - t - math.lgamma(a)) * total
    return max(0.0, 1.0 - lower)


def _rate_and_variances(records: list[dict]) -> tuple[set, float, float, float]:
    """(world keys, rate, variance by flight, variance by world) of pooled ``records``."""
    counts = world_counts(records)
    if len(counts) < 2:
        raise ValueError("pool --split: every group needs at least 2 worlds")
    yc, mc = np.array(list(counts.values())).T
    p, var_world = world_variance(yc, mc)
    var_flight = p * (1 - p) / mc.sum()
    return set(counts), p, var_flight, max(var_world, var_flight)


def groups_differ(groups: list[list[dict]]) -> dict:
    """Test that G groups of records, on disjoint worlds, fly at one rate (module
    docstring): {"df", "shared_worlds", "chi2_flight", "p_flight", "chi2_world",
    "p_world"}."""
    if len(groups) < 2:
        raise ValueError(f"pool --split: needs at least 2 groups to compare; got "
                         f"{len(groups)}")
    stats = [_rate_and_variances(g) for g in groups]
    # Two evaluation seeds draw their worlds from a million seeds, so a world now and then
    # turns up in both (a handful in thousands): negligible. Groups that share more than
    # 5% of their worlds are a paired question instead.
    shared = 0
    for i, (keys_i, *_) in enumerate(stats):
        for keys_j, *_ in stats[i + 1:]:
            both = len(keys_i & keys_j)
            if both > 0.05 * min(len(keys_i), len(keys_j)):
                raise ValueError(f"pool --split: two groups share {both} of their worlds, so "
                                 f"they are not independent samples; compare them paired "
                                 f"(--against)")
            shared += both
    rates = np.array([s[1] for s in stats])
    out = {"df": len(groups) - 1, "shared_worlds": shared}
    for name, col in (("flight", 2), ("world", 3)):
        v = np.array([s[col] for s in stats])
        if not (v > 0).all():
            raise ValueError("pool --split: a group flies every flight alike (rate 0 or "
                             "1), so it has no variance to test against")
        p_bar = float((rates / v).sum() / (1 / v).sum())
        x2 = float(((rates - p_bar) ** 2 / v).sum())
        out[f"chi2_{name}"], out[f"p_{name}"] = x2, chi2_sf(x2, len(groups) - 1)
    return out


def paired_difference(a: list[dict], b: list[dict], z: float = 1.96) -> tuple:
    """Rate of ``a`` minus rate of ``b``, paired by world (module docstring): returns
    (difference, low, high, worlds). Both must have flown the same worlds."""
    if not a or not b:
        raise ValueError(f"pool: both sides need records; got {len(a)} and {len(b)} "
                         f"(check --where and --against)")
    ca, cb = world_counts(a), world_counts(b)
    if ca.keys() != cb.keys():
        raise ValueError(f"pool: the two sides flew different worlds ({len(ca)} and "
                         f"{len(cb)} worlds, {len(ca.keys() & cb.keys())} shared); pair "
                         f"evaluations of the same scenario, seed, flights and chunk")
    keys = sorted(ca)
    ya, ma = (np.array([ca[k][j] for k in keys], np.float64) for j in (0, 1))
    yb, mb = (np.array([cb[k][j] for k in keys], np.float64) for j in (0, 1))
    pa, pb = ya.sum() / ma.sum(), yb.sum() / mb.sum()
    c = len(keys)
    if c < 2:
        raise ValueError("pool: a paired difference needs at least 2 worlds; got 1")
    zc = (ya - pa * ma) / ma.sum() - (yb - pb * mb) / mb.sum()
    half = z * math.sqrt(c / (c - 1) * float((zc ** 2).sum()))
    return pa - pb, pa - pb - half, pa - pb + half, c


def _matches(record: dict, conditions: list[str]) -> bool:
    """Every KEY=VALUE holds: the record's value as text equals VALUE, or matches it as a
    shell pattern (``spec=runs/e37_twin/*``), or one of several joined by commas
    (``seed=12345,24680,31415``)."""
    for cond in conditions:
        key, _, wants = cond.partition("=")
        if key not in record:
            return False
        have = str(record[key])
        if not any(have == want or fnmatch.fnmatchcase(have, want)
                   for want in wants.split(",")):
            return False
    return True


def against_conditions(where: list[str], against: list[str]) -> list[str]:
    """The second group's conditions: --where's, with the keys --against names replaced
    (``--where scenario=corners --against spec=reactive``: the reactive rule in corners)."""
    replaced = {c.partition("=")[0] for c in against}
    return [c for c in where if c.partition("=")[0] not in replaced] + list(against)


def read_records(paths) -> list[dict]:
    records = []
    for path in paths:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"pool: no such results file: {path}")
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if line.strip():
                try:
                    records.append(json.loads(line))
                except json.JSONDecodeError as e:
                    raise ValueError(f"pool: {path} line {n} is not a JSON record "
                                     f"(evaluate --json writes one per line): {e}") from None
    return records


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("files", nargs="+", help="JSON-lines files written by evaluate --json")
    p.add_argument("--where", action="append", default=[], metavar="KEY=VALUE",
                   help="keep records whose KEY is VALUE (a shell pattern allowed: "
                        "'spec=runs/*'; or any of several: seed=12345,24680); "
                        "repeat to require several")
    p.add_argument("--against", action="append", default=[], metavar="KEY=VALUE",
                   help="a second group: the --where conditions with these keys "
                        "replaced; print the first group's rate minus this one's, paired "
                        "by world")
    p.add_argument("--split", default=None, metavar="KEY",
                   help="also pool each value of KEY apart (e.g. seed: each set of test "
                        "worlds) and test whether the groups' rates differ")
    p.add_argument("--each", action="store_true", help="print each record's line too")


def _check_conditions(conditions: list[str], flag: str) -> None:
    for cond in conditions:
        if "=" not in cond or not cond.partition("=")[0]:
            raise UsageError(f"{flag}: expected KEY=VALUE (e.g. scenario=basic); "
                             f"got {cond!r}")


def run(args) -> int:
    _check_conditions(args.where, "--where")
    _check_conditions(args.against, "--against")
    try:
        return _run(args)
    except (ValueError, FileNotFoundError) as e:     # our own messages, not a traceback
        raise UsageError(str(e).removeprefix("pool: ")) from None


def _run(args) -> int:
    records = read_records(args.files)
    group = [r for r in records if _matches(r, args.where)]
    if args.each:
        for r in group:
            print(f"  {r.get('spec', r['policy'])} {r['scenario']} seed {r['seed']}: "
                  f"{r['rate']:.4f} ({r['successes']}/{r['flights']})")
    print(pool_records(group).line("pooled"))
    if args.split:
        values = sorted({str(r.get(args.split)) for r in group})
        parts = [[r for r in group if str(r.get(args.split)) == v] for v in values]
        for v, part in zip(values, parts):
            print("  " + pool_records(part).line(f"{args.split}={v}"))
        try:
            t = groups_differ(parts)
        except ValueError as e:        # no test possible; the groups' lines still stand
            n = f" {len(parts)}" if len(parts) > 1 else ""
            print(f"do the{n} groups differ? no test: {e}")
        else:
            note = (f" ({t['shared_worlds']} world(s) drawn by two groups, ignored)"
                    if t["shared_worlds"] else "")
            print(f"do the {len(parts)} groups differ? chi-square ({t['df']} df) by flight "
                  f"{t['chi2_flight']:.2f}, p = {t['p_flight']:.3f}; by world "
                  f"{t['chi2_world']:.2f}, p = {t['p_world']:.3f}{note}")
    if args.against:
        other = [r for r in records if _matches(r, against_conditions(args.where,
                                                                        args.against))]
        print(pool_records(other).line("against"))
        d, lo, hi, c = paired_difference(group, other)
        print(f"difference, paired by world: {d:+.4f} [{lo:+.4f}, {hi:+.4f}] ({c} worlds)")
    return 0
