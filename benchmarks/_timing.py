"""What the benchmark scripts share: how a callable is timed, how each thread count gets
a process of its own, and how a table of results is printed. What is timed (the cases,
ours and torch's) stays in each script.

Timing (``measure``, ``median_ms``): each callable runs ``warmup`` times untimed, then
``repeat`` rounds in which every callable runs once, in the order given, each call timed
on its own. Given ours and torch's, the two alternate, so load from other processes hits
both alike. The result is each callable's median in ms (``stat=min``: its fastest run,
the least disturbed one). The clock is the wall clock (``time.perf_counter``) or, for
``--clock cpu``, the process's CPU time (``time.process_time``): preemption by other
processes no longer counts, but the CPU time of all threads adds up, so it measures one
thread only.

Threads (``thread_counts``, ``thread_env``, ``run_child``, ``load_torch``): OpenBLAS and
MKL read OMP_NUM_THREADS, OPENBLAS_NUM_THREADS and MKL_NUM_THREADS once, when NumPy
loads. A script that compares thread counts therefore re-runs itself once per count, in a
child process with the three set to that count; the child gives torch the same number
(``torch.set_num_threads``) and prints its results as its last line, in JSON.

Options (``positive_int``, ``case_names``, ``thread_counts``): checked where they are
read, a bad value refused in one line naming the option; ``cases_over_threads`` is the
whole command line of a script that times cases at some thread counts. Tables (``print_table``,
``fmt``): fixed-width columns, then free notes.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}   # the --clock choices


# -- timing ------------------------------------------------------------------------------
def measure(fns: dict, repeat: int, warmup: int = 3, clock=time.perf_counter,
            stat=statistics.median) -> dict:
    """``{name: ms}`` for the callables ``fns`` (``{name: fn}``): ``warmup`` untimed calls
    of each, then ``repeat`` rounds calling each once in turn, reduced by ``stat``."""
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    times = {name: [] for name in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            t0 = clock()
            fn()
            times[name].append(1e3 * (clock() - t0))
    return {name: float(stat(ts)) for name, ts in times.items()}


def median_ms(fn, repeat: int, warmup: int = 3, clock=time.perf_counter) -> float:
    """The median ms of ``repeat`` timed calls of ``fn``, after ``warmup`` untimed ones."""
    return measure({"fn": fn}, repeat, warmup, clock)["fn"]


# -- options -----------------------------------------------------------------------------
def positive_int(text: str) -> int:
    """An argparse ``type``: a whole number of 1 or more (``--repeat``)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole number; got {text!r}")
    return value


def case_names(parser, text: str, known) -> list[str]:
    """The case names of ``--cases`` ("act,depth"), each one of ``known``."""
    cases = [c for c in text.split(",") if c]
    unknown = set(cases) - set(known)
    if unknown:
        parser.error(f"--cases: unknown {sorted(unknown)}; choose from {','.join(known)}")
    return cases


def thread_counts(parser, text: str, clock: str = "wall") -> list[int]:
    """The thread counts of ``--threads`` ("1,2"); with ``--clock cpu`` only 1."""
    try:
        threads = [int(t) for t in text.split(",") if t]
    except ValueError:
        threads = []
    if not threads or min(threads) < 1:
        parser.error(f"--threads: expected comma-separated positive whole numbers; "
                     f"got {text!r}")
    if clock == "cpu" and threads != [1]:
        parser.error("--clock cpu measures one thread only: use it with --threads 1")
    return threads


# -- one process per thread count --------------------------------------------------------
def thread_env(threads: int) -> dict:
    """This process's environment with the BLAS thread counts set to ``threads``."""
    n = str(threads)
    return dict(os.environ, OMP_NUM_THREADS=n, OPENBLAS_NUM_THREADS=n, MKL_NUM_THREADS=n)


def run_child(script: str, threads: int, args: list[str]):
    """Runs ``python script *args`` with ``threads`` BLAS threads; the JSON value of its
    last output line. A failed child ends this process with the child's error output."""
    proc = subprocess.run([sys.executable, os.path.abspath(script), *args],
                          env=thread_env(threads), capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"the {threads}-thread run failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def load_torch(threads: int):
    """torch with ``threads`` threads, or None where torch is not installed."""
    try:
        import torch
    except ImportError:
        return None
    torch.set_num_threads(threads)
    return torch


def cases_over_threads(argv, doc: str, script: str, known, worker, print_rows,
                       repeat_help: str, json_option: bool = False) -> None:
    """The command line of a script that times ``known`` cases at some thread counts:
    ``--threads``, ``--cases``, ``--repeat``, ``--clock`` (and ``--json``). It re-runs
    ``script`` once per thread count (``run_child``), where ``worker(threads, cases,
    repeat, clock)`` returns the rows, and prints them with ``print_rows(rows, repeat,
    clock)``."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--threads", default="1,2",
                        help="comma-separated thread counts, one child process each")
    parser.add_argument("--cases", default=",".join(known), help=f"from {','.join(known)}")
    parser.add_argument("--repeat", type=positive_int, default=10, help=repeat_help)
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="wall clock, or the process's CPU time (one thread only)")
    if json_option:
        parser.add_argument("--json", action="store_true", help="print the rows as JSON lines")
    parser.add_argument("--worker", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    cases = case_names(parser, args.cases, known)
    if args.worker is not None:
        print(json.dumps(worker(args.worker, cases, args.repeat, args.clock)))
        return
    rows = []
    for n in thread_counts(parser, args.threads, args.clock):
        rows += run_child(script, n, ["--worker", str(n), "--cases", ",".join(cases),
                                      "--repeat", str(args.repeat), "--clock", args.clock])
    if json_option and args.json:
        for r in rows:
            print(json.dumps(r))
    print_rows(rows, args.repeat, args.clock)


# -- tables ------------------------------------------------------------------------------
def fmt(value, spec: str) -> str:
    """``value`` formatted by ``spec`` (".3f"), or "-" where there is none (no torch)."""
    return "-" if value is None else format(value, spec)


def print_table(columns: list[tuple[str, int]], rows: list[list[str]], footer: str) -> None:
    """A table with a column of each (title, width) in ``columns`` (the first aligned
    left, the others right) and a last, free column "notes"; ``rows``: the cells of each
    row as strings, its notes last; ``footer``: the line below."""
    def line(cells):
        (first, (_, width)), *rest = zip(cells, columns)
        aligned = [f"{first:{width}s}"] + [f"{cell:>{w}s}" for cell, (_, w) in rest]
        return " ".join(aligned) + f"  {cells[-1]}"
    head = line([title for title, _ in columns] + ["notes"])
    print(head)
    print("-" * len(head))
    for cells in rows:
        print(line(cells))
    print(footer)
