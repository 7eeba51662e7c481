"""Where the process-parallel work runs: a local pool of forked workers, or Ray.

The work that can be split is split into independent *tasks*: the chunks of an
evaluation (``rl/evaluate.py``), the trainings of a reproduction, of distillation's
students and of a seed sweep (``rl/reproduce.py``, ``rl/sweep.py``). Each task's result
is fixed by its own arguments (its chunk's seed, its run's seed), so it is the same in
any process, on any machine, in any order: an executor only decides where it runs.

    executor = get_executor("local" | "ray", workers)
    results = executor.run(fn, tasks, shared, on_result)   # fn(shared, task) each, in order

``shared`` (the policy and the depth model of an evaluation) is sent once: forked
workers inherit it, Ray puts it in its object store.

**The local pool** (the default) forks ``workers`` processes (one per core). They follow
their parent:

- Ctrl-C and SIGTERM reach every worker through the parent (workers sit in a process
  group of their own, so a terminal's Ctrl-C is not delivered twice): a training stops
  at the end of its step with its checkpoint saved; the parent then raises
  ``io.RunStopped`` naming every stopped run, and the command line prints the command
  that continues. A second Ctrl-C stops at once.
- When the parent dies (``kill -9``), its workers are killed within a second (Linux:
  ``prctl(PR_SET_PDEATHSIG)``; elsewhere a thread that watches the parent's pid), so
  nothing goes on training or writing behind a dead command; what a killed training
  lost is what the parent alone would have lost: the steps since its last checkpoint.
- A task lost with its worker (the worker killed, e.g. by the out-of-memory killer)
  runs again on a new worker, up to ``RETRIES`` times, as Ray reruns a lost task; a
  training run again resumes from its last checkpoint, a chunk flies the same flights.

**Ray** (``--executor ray``, ``pip install -e ".[ray]"``) runs each task as a Ray task
(one CPU each) on the cluster ``ray.init()`` finds: ``RAY_ADDRESS``, or a local one
started for the run. Ray reruns a task lost with its node or its worker
(``max_retries``). Ctrl-C and SIGTERM of the command reach every task as Ctrl-C
(``ray.cancel``): a training saves its checkpoint and the stopped runs are named, as
with the local pool; a task not yet started does not start. Trainings read and write
their run folders there, so the folders (and the working directory, for relative paths)
must be on storage every node mounts at the same path: each task checks that it sees a
marker file the driver wrote, and a task that does not fails in one line.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import signal
import sys
import threading
import time
import traceback
import uuid
import warnings
from pathlib import Path

from .config import UsageError
from .io import RunStopped

EXECUTORS = ("local", "ray")
RETRIES = 3          # reruns of a task lost with its worker (Ray's default max_retries)


class WorkerLost(RuntimeError):
    """A task whose worker died ``RETRIES`` + 1 times; the CLI prints it as one line."""


# -- SIGTERM as Ctrl-C ---------------------------------------------------------------------
def _term_as_int(signum, frame):
    handler = signal.getsignal(signal.SIGINT)
    if callable(handler):
        handler(signal.SIGINT, frame)
    else:                                 # SIG_IGN / SIG_DFL set from outside Python
        raise KeyboardInterrupt


def sigterm_as_ctrl_c() -> None:
    """From now on SIGTERM (what ``kill``, ``timeout`` and schedulers send) does what
    Ctrl-C does at that moment: a training saves its checkpoint and stops, a pool stops
    its workers. Main thread only (signal handlers are set there)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _term_as_int)


# -- a worker follows its parent -------------------------------------------------------------
PR_SET_PDEATHSIG = 1


def follow_parent(parent: int, poll: float = 0.5) -> None:
    """In a worker process: die (SIGKILL) as soon as process ``parent`` is gone. Linux:
    the kernel does it (``prctl(PR_SET_PDEATHSIG)``); elsewhere a daemon thread polls
    ``os.getppid()`` every ``poll`` seconds."""
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        armed = sys.platform.startswith("linux") and \
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        armed = False
    if os.getppid() != parent:            # the parent died before the line above
        os._exit(1)
    if armed:
        return

    def watch():
        while os.getppid() == parent:
            time.sleep(poll)
        os.kill(os.getpid(), getattr(signal, "SIGKILL", signal.SIGTERM))
    threading.Thread(target=watch, name="follow-parent", daemon=True).start()


# -- the local pool ----------------------------------------------------------------------------
def _picklable(error: BaseException) -> BaseException:
    try:
        pickle.loads(pickle.dumps(error))
        return error
    except Exception:
        text = "".join(traceback.format_exception(type(error), error, error.__traceback__))
        return RuntimeError(f"{type(error).__name__}: {error} (in a worker)\n{text}")


def _worker(conn, fn, shared, parent: int) -> None:
    """A worker's life: tasks from ``conn`` until None; each answered with (index, kind,
    value), kind "ok", "stopped" (a training stopped by Ctrl-C: value its message),
    "interrupted" or "error"."""
    follow_parent(parent)
    os.setpgid(0, 0)     # a terminal's Ctrl-C reaches the parent only; it passes it on once
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _term_as_int)
    index = None
    try:
        while True:
            message = conn.recv()
            if message is None:
                break
            index, task = message
            try:
                conn.send((index, "ok", fn(shared, task)))
            except RunStopped as e:
                conn.send((index, "stopped", str(e)))
                break
            except KeyboardInterrupt:
                conn.send((index, "interrupted", None))
                break
            except BaseException as e:    # noqa: BLE001 (the parent raises it)
                conn.send((index, "error", _picklable(e)))
            index = None
    except KeyboardInterrupt:             # between tasks
        if index is not None:
            conn.send((index, "interrupted", None))
    except (EOFError, BrokenPipeError):   # the parent is gone
        pass


def _exit_reason(process) -> str:
    code = process.exitcode
    if code is not None and code < 0:
        try:
            return f"killed by signal {-code} ({signal.Signals(-code).name})"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


class _Stop:
    """The parent's Ctrl-C during a pool's run: the first one is passed on to every
    worker (``forward``), a second one interrupts at once."""

    def __init__(self, forward):
        self.requested, self.forward = False, forward
        self._old, self._installed = None, False

    def _handle(self, signum, frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        self.forward()

    def __enter__(self):
        self._installed = threading.current_thread() is threading.main_thread()
        if self._installed:
            self._old = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc):
        if self._installed:
            signal.signal(signal.SIGINT, self._old if self._old is not None
                          else signal.default_int_handler)
        return False


def _stopped(messages: list[str]) -> BaseException:
    """What a pool stopped by Ctrl-C raises: RunStopped naming each training stopped with
    its checkpoint, else KeyboardInterrupt."""
    if not messages:
        return KeyboardInterrupt()
    runs = f"{len(messages)} run" + ("s" if len(messages) > 1 else "")
    return RunStopped(f"{runs} stopped with {'their' if len(messages) > 1 else 'its'} "
                      f"checkpoint ({'; '.join(messages)})")


class LocalPool:
    """``workers`` forked processes (module docstring); one worker, or a platform that
    cannot fork: the tasks run one after the other in this process."""

    name = "local"

    def __init__(self, workers: int = 1):
        if workers < 1:
            raise ValueError(f"LocalPool: workers must be >= 1; got {workers}")
        self.workers = workers

    def run(self, fn, tasks: list, shared=None, on_result=None, *, check_folders=()) -> list:
        """``fn(shared, task)`` for every task; the results in the tasks' order.
        ``on_result(index, result)`` is called as each task finishes (a progress bar).
        ``check_folders``: folders the tasks write (the local pool's workers share this
        machine's files: nothing to check)."""
        tasks = list(tasks)
        workers = min(self.workers, len(tasks))
        if workers > 1 and "fork" not in mp.get_all_start_methods():
            warnings.warn("this platform cannot fork; running the tasks in one process",
                          RuntimeWarning, stacklevel=2)
            workers = 1
        if workers <= 1:
            results = []
            for i, task in enumerate(tasks):
                results.append(fn(shared, task))
                if on_result is not None:
                    on_result(i, results[-1])
            return results
        return self._run_forked(fn, tasks, shared, on_result, workers)

    def _run_forked(self, fn, tasks, shared, on_result, workers) -> list:
        from multiprocessing.connection import wait
        ctx = mp.get_context("fork")
        parent = os.getpid()
        todo = list(range(len(tasks)))[::-1]          # popped from the end: in order
        lost = [0] * len(tasks)
        results, done = [None] * len(tasks), [False] * len(tasks)
        live = {}              # connection -> [process, index of its task or None]
        stopped, error = [], None

        def start():
            mine, theirs = ctx.Pipe()
            p = ctx.Process(target=_worker, args=(theirs, fn, shared, parent), daemon=True)
            p.start()
            theirs.close()
            live[mine] = [p, None]

        def give(conn):
            if todo and not stop.requested and error is None:
                live[conn][1] = todo.pop()
                conn.send((live[conn][1], tasks[live[conn][1]]))
            else:
                live[conn][1] = None
                try:
                    conn.send(None)
                except (BrokenPipeError, OSError):
                    pass

        def forward(sig=signal.SIGINT):
            for p, _ in list(live.values()):
                if p.is_alive():
                    try:
                        os.kill(p.pid, sig)
                    except ProcessLookupError:
                        pass

        with _Stop(forward) as stop:
            try:
                for _ in range(workers):
                    start()
                for conn in list(live):
                    give(conn)
                while live:
                    ready = wait(list(live) + [p.sentinel for p, _ in live.values()], 0.2)
                    for conn in [c for c in list(live) if c in ready or
                                 live[c][0].sentinel in ready]:
                        p, index = live[conn]
                        try:
                            message = conn.recv() if conn.poll() else None
                        except (EOFError, OSError):
                            message = None
                        if message is None:             # the worker is gone
                            if p.is_alive() and index is not None:
                                continue                # not yet: its answer is on its way
                            p.join()
                            del live[conn]
                            conn.close()
                            if index is None or done[index]:
                                continue
                            if stop.requested or error is not None:
                                continue
                            lost[index] += 1
                            if lost[index] > RETRIES:
                                error = WorkerLost(
                                    f"task {index + 1} of {len(tasks)} lost its worker "
                                    f"{lost[index]} times (last: {_exit_reason(p)})")
                                forward()
                                continue
                            print(f"a worker was lost ({_exit_reason(p)}) running task "
                                  f"{index + 1} of {len(tasks)}; running it again "
                                  f"(rerun {lost[index]} of {RETRIES})", file=sys.stderr,
                                  flush=True)
                            todo.append(index)
                            start()
                            give(list(live)[-1])
                            continue
                        index, kind, value = message
                        if kind == "ok":
                            results[index], done[index] = value, True
                            if on_result is not None:
                                on_result(index, value)
                            give(conn)
                        elif kind in ("stopped", "interrupted"):
                            if kind == "stopped":
                                stopped.append(value)
                            if not stop.requested:   # a worker stopped alone: all stop
                                stop.requested = True
                                forward()
                        elif error is None:             # the first error: stop the rest
                            error = value
                            forward()
                            give(conn)
                        else:
                            give(conn)
            except BaseException:
                forward(signal.SIGKILL)
                raise
            finally:
                for p, _ in live.values():
                    p.join(timeout=1)
                    if p.is_alive():
                        p.kill()
                        p.join()
                for conn in live:
                    conn.close()
        if error is not None:
            raise error
        if stop.requested or not all(done):
            raise _stopped(stopped)
        return results


# -- Ray ---------------------------------------------------------------------------------------
MARKER = ".minid3rqn-executor-{}"


def _ray_task(fn, shared, task, cwd: str, markers: list[str], reports):
    """One task on a Ray worker, in the driver's working directory, after checking that
    the folders it writes are the driver's (each holds the driver's marker file). The
    driver's Ctrl-C reaches it as Ctrl-C (``ray.cancel``): a training saves its
    checkpoint, and its RunStopped message goes to the driver's ``reports`` actor."""
    import socket
    try:
        os.chdir(cwd)
    except OSError:
        raise NotShared(f"the driver's working directory {cwd!r} does not exist on "
                        f"{socket.gethostname()}") from None
    for marker in markers:
        if not os.path.isfile(marker):
            raise NotShared(f"{str(Path(marker).parent)!r} is not on storage shared with "
                            f"{socket.gethostname()} (it cannot see the driver's marker file)")
    try:
        return fn(shared, task)
    except RunStopped as e:              # Ray turns a raised KeyboardInterrupt into a
        import ray                       # cancellation: the message goes this way
        ray.get(reports.report.remote(str(e)))
        return _Stopped(str(e))
    except KeyboardInterrupt:
        return _Stopped(None)


class _Stopped:
    """What a Ray task stopped by Ctrl-C returns: a training's RunStopped message."""

    def __init__(self, message):
        self.message = message


class _Reports:
    """The RunStopped messages of the trainings the driver's Ctrl-C stopped."""

    def __init__(self):
        self.messages = []

    def report(self, message: str) -> None:
        self.messages.append(message)

    def all(self) -> list:
        return self.messages


class NotShared(Exception):
    """A Ray worker cannot see a folder the driver writes."""


def _import_ray():
    try:
        import ray
    except ImportError:
        raise UsageError('--executor ray: ray is not installed (pip install -e ".[ray]", '
                         'or leave --executor at local)') from None
    return ray


class RayExecutor:
    """Each task a Ray task (one CPU) on the cluster ``ray.init()`` finds (module
    docstring); ``shared`` goes once through the object store."""

    name = "ray"

    def __init__(self, workers: int | None = None):
        self.ray = _import_ray()
        self.workers = workers

    def _init(self):
        ray = self.ray
        if not ray.is_initialized():
            # the workers import this copy of minid3rqn, as this process does (where the
            # node has it at the same path: a shared file system; else their own install)
            root = str(Path(__file__).resolve().parent.parent)
            path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)
            env = {"env_vars": {"PYTHONPATH": path}}
            handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
            ray.init(runtime_env=env, log_to_driver=True, configure_logging=False)
            if threading.current_thread() is threading.main_thread():
                for sig, handler in handlers.items():   # Ctrl-C and SIGTERM stay ours
                    if handler is not None:
                        signal.signal(sig, handler)

    def run(self, fn, tasks: list, shared=None, on_result=None, *, check_folders=()) -> list:
        """As ``LocalPool.run``; ``check_folders``: the folders the tasks write, which
        every worker must see (``NotShared`` becomes a one-line UsageError)."""
        ray = self.ray
        tasks = list(tasks)
        if not tasks:
            return []
        self._init()
        markers = self._markers(check_folders)
        remote = ray.remote(num_cpus=1, max_retries=RETRIES)(_ray_task)
        reports = ray.remote(num_cpus=0)(_Reports).remote()
        cwd = os.getcwd()
        shared_ref = ray.put(shared)
        refs = [remote.remote(fn, shared_ref, task, cwd, markers, reports) for task in tasks]
        index = {ref: i for i, ref in enumerate(refs)}
        results = [None] * len(tasks)
        pending = list(refs)
        stopped = []
        try:
            while pending:
                ready, pending = ray.wait(pending, num_returns=1, timeout=0.5)
                for ref in ready:
                    result = self._get(ref)
                    if isinstance(result, _Stopped):    # stopped on its node: all stop
                        stopped.append(result)
                        raise KeyboardInterrupt
                    results[index[ref]] = result
                    if on_result is not None:
                        on_result(index[ref], result)
        except KeyboardInterrupt:
            raise self._stop(pending, reports, stopped) from None
        except BaseException:
            for ref in pending:
                ray.cancel(ref, force=True)
            raise
        finally:
            for marker in markers:
                Path(marker).unlink(missing_ok=True)
        return results

    @staticmethod
    def _markers(folders) -> list[str]:
        """A marker file in each folder the tasks write (made if missing): a task that
        cannot see it runs where the folder is not shared."""
        markers = []
        for folder in dict.fromkeys(Path(f).resolve() for f in folders):
            folder.mkdir(parents=True, exist_ok=True)
            marker = folder / MARKER.format(uuid.uuid4().hex)
            marker.write_text(f"written by pid {os.getpid()} to check that Ray's workers "
                              f"share this folder; removed when the tasks end\n")
            markers.append(str(marker))
        return markers

    def _get(self, ref):
        ray = self.ray
        try:
            return ray.get(ref)
        except ray.exceptions.RayTaskError as e:
            cause = e.cause if getattr(e, "cause", None) is not None else e
            if isinstance(cause, NotShared):
                raise UsageError(f"--executor ray: {cause}; put the run folders on a file "
                                 f"system every node mounts at the same path") from None
            raise cause from None

    def _stop(self, pending, reports, stopped) -> BaseException:
        """Ctrl-C: every task is interrupted as by Ctrl-C (a training saves its
        checkpoint; a task not started does not start), and the stopped trainings are
        named. A second Ctrl-C ends every task at once."""
        ray = self.ray
        for ref in pending:
            ray.cancel(ref, force=False)
        try:
            for ref in pending:
                try:
                    ray.get(ref)
                except ray.exceptions.RayError:
                    pass
            messages = ray.get(reports.all.remote())
        except KeyboardInterrupt:
            for ref in pending:
                ray.cancel(ref, force=True)
            return KeyboardInterrupt()
        messages += [s.message for s in stopped if s.message and s.message not in messages]
        return _stopped(messages)


def get_executor(name: str = "local", workers: int = 1):
    """The executor called ``name`` (EXECUTORS) with ``workers`` local processes."""
    if name == "local":
        return LocalPool(workers)
    if name == "ray":
        return RayExecutor(workers)
    raise ValueError(f"get_executor: expected one of {', '.join(EXECUTORS)}; got {name!r}")
