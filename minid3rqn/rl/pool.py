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
        --where 'spec=runs/nets/*' --against spec=reactive

``--against`` keeps the ``--where`` conditions it does not name: above, the reactive rule
in intersections.
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
from .evaluate import clustered_interval, wilson_interval


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
    shell pattern (``spec=runs/nets/*``), or one of several joined by commas
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


def _record_problem(r) -> str | None:
    """What makes ``r`` not an evaluation record that can be pooled, or None."""
    if not isinstance(r, dict):
        return "is not a JSON object"
    if not isinstance(r.get("scenario"), str):
        return "names no scenario"
    seeds, successes, flights = (r.get(k) for k in ("world_seeds", "world_successes",
                                                       "world_flights"))
    if seeds is None:
        return None                      # an older record: world_counts says so

    def counts(x) -> bool:               # one whole number per world
        return isinstance(x, list) and len(x) == len(seeds) and all(
            isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 2 ** 40 for v in x)
    if not (isinstance(seeds, list) and counts(successes) and counts(flights)) or any(
            y > m or m < 1 for y, m in zip(successes, flights)):
        return ("has world counts that do not match (world_seeds, world_successes and "
                "world_flights: lists of one length, 0 <= successes <= flights, flights >= 1)")
    return None


def read_records(paths) -> list[dict]:
    records = []
    for path in paths:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"pool: no such results file: {path}")
        try:
            lines = path.read_text().splitlines()
        except UnicodeDecodeError:
            raise ValueError(f"pool: {path} is not a text file (evaluate --json writes "
                             f"JSON lines)") from None
        for n, line in enumerate(lines, 1):
            if line.strip():
                try:
                    record = json.loads(line)
                except json.JSONDecodeError as e:
                    raise ValueError(f"pool: {path} line {n} is not a JSON record "
                                     f"(evaluate --json writes one per line): {e}") from None
                problem = _record_problem(record)
                if problem:
                    raise ValueError(f"pool: {path} line {n} {problem}")
                records.append(record)
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
    print(pool_records(group).line("pooled"))
    if args.against:
        other = [r for r in records if _matches(r, against_conditions(args.where,
                                                                        args.against))]
        print(pool_records(other).line("against"))
        d, lo, hi, c = paired_difference(group, other)
        print(f"difference, paired by world: {d:+.4f} [{lo:+.4f}, {hi:+.4f}] ({c} worlds)")
    return 0
