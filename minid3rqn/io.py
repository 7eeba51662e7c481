"""Files on disk: ``.npz`` written atomically, read without pickle; JSON lines
appended whole; run folders and output paths checked before a command works; a
training loop stopped by Ctrl-C at the end of a step.

Atomic: the arrays go to a temporary file in the same folder, which is then renamed
over the target; a crash mid-write leaves the old file intact, never half a file. A
temporary file left by a writer that was killed is removed by the next write to the
same path. Files get the usual permissions (0666 less the umask), as ``open`` gives.
"""
from __future__ import annotations

import json
import os
import signal
import sys
import tempfile
import threading
import zipfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _remove_stale_temporaries(path: Path) -> None:
    """Delete ``path``'s temporary files whose writer (its pid is in the name) is gone."""
    for tmp in path.parent.glob(path.name + ".*.tmp"):
        pid = tmp.name[len(path.name) + 1:].split(".", 1)[0]
        if not pid.isdigit():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            tmp.unlink(missing_ok=True)
        except PermissionError:        # alive, another user's
            pass


def save_npz(path, arrays: dict[str, np.ndarray], metadata: dict | None = None) -> Path:
    """Write ``arrays`` (and optional JSON-able ``metadata``) to ``path`` atomically."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"save_npz: path must end in .npz; got {str(path)!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {k: np.asarray(v) for k, v in arrays.items()}
    if metadata is not None:
        if "__metadata__" in payload:
            raise ValueError("save_npz: the key '__metadata__' is reserved")
        payload["__metadata__"] = np.asarray(json.dumps(metadata))
    for key, value in payload.items():
        if value.dtype == object:
            raise TypeError(f"save_npz: array {key!r} has dtype object, which would need "
                            f"pickle; store numbers or strings only")
    _remove_stale_temporaries(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f"{path.name}.{os.getpid()}.",
                               suffix=".tmp")
    try:
        os.chmod(tmp, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **payload)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return path


def _npz_problem(error: Exception) -> str:
    """NumPy's reason a file is no .npz, without its advice to unpickle a file."""
    return "it is not an .npz file" if "pickle" in str(error) else str(error)


def load_npz(path) -> tuple[dict[str, np.ndarray], dict | None]:
    """Read ``path`` written by ``save_npz``: (arrays, metadata or None)."""
    path = Path(path)
    if not path.is_file():
        what = "a folder" if path.is_dir() else "no file"
        raise FileNotFoundError(f"{str(path)!r} is {what}; expected an .npz file")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        meta = arrays.pop("__metadata__", None)
        return arrays, (json.loads(str(meta)) if meta is not None else None)
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as e:
        raise ValueError(f"{str(path)!r} is not a readable .npz file (truncated, or not "
                         f"written by minid3rqn): {_npz_problem(e)}") from None


def read_metadata(path) -> dict | None:
    """The metadata of an .npz written by ``save_npz``, without reading its arrays."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{str(path)!r} is no file; expected an .npz file")
    try:
        with np.load(path, allow_pickle=False) as data:
            if "__metadata__" not in data.files:
                return None
            return json.loads(str(data["__metadata__"]))
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as e:
        raise ValueError(f"{str(path)!r} is not a readable .npz file (truncated, or not "
                         f"written by minid3rqn): {_npz_problem(e)}") from None


def _last_line_problem(path: Path) -> str | None:
    """Why records may not be appended to the JSON-lines log ``path``, or None."""
    data = path.read_bytes()
    if not data:
        return None
    if not data.endswith(b"\n"):
        return f"{str(path)!r}: its last line is incomplete; repair the file before appending to it"
    try:
        record = json.loads(data.rstrip(b"\n").rsplit(b"\n", 1)[-1])
    except ValueError:
        record = None
    if not isinstance(record, dict):
        return f"{str(path)!r}: its last line is not a JSON record; expected a JSON-lines log"
    return None


def append_jsonl(path, record: dict) -> None:
    """Append ``record`` as one JSON line to ``path``, whole or not at all.

    The line is written with one ``write``; if that fails (a full disk), the file is cut
    back to its old length, so a results log never holds half a record. A log whose last
    line is incomplete is refused rather than extended."""
    path = Path(path)
    line = (json.dumps(record) + "\n").encode()
    problem = _last_line_problem(path) if path.is_file() else None
    if problem:
        raise ValueError(problem)
    with open(path, "ab") as f:
        size = f.seek(0, os.SEEK_END)
        try:
            f.write(line)
            f.flush()
            os.fsync(f.fileno())
        except BaseException:
            f.truncate(size)
            raise


def blas_core() -> str:
    """The CPU kernel set NumPy's OpenBLAS chose on this machine ("Haswell", "SkylakeX", ...),
    or "unknown" where it cannot be asked (another BLAS, another wheel layout).

    Why it matters: OpenBLAS is built for many CPUs at once (``DYNAMIC_ARCH``) and picks
    its matrix kernels for the CPU it finds. Kernels for different CPUs add up a
    product's terms in a different order (and fuse multiply-adds differently), so float32
    results differ in the last bits, and a long RL run, where one different action sends
    every later step elsewhere, ends as another draw of the same recipe. The same seed
    gives the same run on machines with the same kernels; the environment variable
    ``OPENBLAS_CORETYPE`` (set before NumPy is imported) chooses them by hand. Training
    commands record this name in their model files (docs/d3rqn.md section 7).
    """
    import ctypes
    import glob
    libs = Path(np.__file__).resolve().parent.parent / "numpy.libs"
    for lib in sorted(glob.glob(str(libs / "*openblas*"))):
        try:
            handle = ctypes.CDLL(lib)
        except OSError:
            continue
        for name in ("scipy_openblas_get_corename64_", "openblas_get_corename64_",
                     "scipy_openblas_get_corename", "openblas_get_corename"):
            fn = getattr(handle, name, None)
            if fn is not None:
                fn.restype = ctypes.c_char_p
                return fn().decode("ascii", "replace")
    return "unknown"


def machine() -> dict:
    """What a saved model records of the machine that trained it (see ``blas_core``)."""
    import platform
    return {"numpy": np.__version__, "blas_core": blas_core(),
            "python": platform.python_version(), "platform": platform.machine()}


# -- output paths and run folders, checked before a command works ---------------------
# A folder holds a run when it has one of these: a checkpoint, or the model it wrote.
RUN_MARKS = ("checkpoint.npz", "model.npz")


def check_output(path, option: str, folder: bool = False, suffix: str | None = None) -> Path:
    """Check, before any work, that ``path`` (given with ``option``) can be written: a
    file (a folder, with ``folder``) outside ``minid3rqn/models`` (the shipped models:
    ``rl.models.ship`` writes there), not a folder where a file is meant or the other way
    round, ending in ``suffix`` if given, in a folder that exists or can be made and is
    writable. Creates nothing; a UsageError naming ``option`` otherwise."""
    from .config import UsageError
    path = Path(path)
    where = path.resolve()
    if where == MODELS or MODELS in where.parents:
        raise UsageError(f"{option}: {str(path)!r} is inside minid3rqn/models, which holds "
                         f"the shipped models; write it elsewhere (e.g. under runs/)")
    if suffix and path.suffix != suffix:
        raise UsageError(f"{option}: expected a {suffix} file; got {str(path)!r}")
    if any(len(part.encode()) > 255 for part in where.parts):
        raise UsageError(f"{option}: {str(path)!r} has a name longer than 255 bytes")
    if path.exists():
        if path.is_dir() != folder:
            kind = "folder" if path.is_dir() else "file"
            raise UsageError(f"{option}: {str(path)!r} is a {kind}; expected "
                             f"{'a folder' if folder else 'a file'}")
        if not os.access(path, os.W_OK):
            raise UsageError(f"{option}: {str(path)!r} is not writable")
        return path
    parent = where.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise UsageError(f"{option}: {str(path)!r} cannot be made: {str(parent)!r} is a file")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"{option}: {str(path)!r} cannot be made: {str(parent)!r} is not "
                         f"writable")
    return path


def check_new_file(path, option: str, suffix: str, existing: str | None) -> Path:
    """``check_output`` for a file a command writes whole: one that exists already is
    replaced only with ``--overwrite`` (``existing`` "overwrite")."""
    from .config import UsageError
    path = check_output(path, option, suffix=suffix)
    if path.exists() and existing != "overwrite":
        raise UsageError(f"{option}: {str(path)!r} exists; give --overwrite to replace it")
    return path


def check_log(path, option: str) -> Path:
    """``check_output`` for a JSON-lines log (``.jsonl``) that records are appended to:
    also refused if its last line is not a whole JSON record (``append_jsonl`` would
    refuse it after the work)."""
    from .config import UsageError
    path = check_output(path, option, suffix=".jsonl")
    problem = _last_line_problem(path) if path.is_file() else None
    if problem:
        raise UsageError(f"{option}: {problem}")
    return path


def claim_run_folder(folder, existing: str | None, option: str,
                     outputs: tuple = RUN_MARKS, inputs: dict | None = None) -> bool:
    """Check, before a training command works, that it may write its run into ``folder``
    (given with ``option``); returns True if it continues the run there.

    A folder that holds a run (``RUN_MARKS``) is written to only by an explicit choice:
    ``existing`` "resume" continues the run from its checkpoint; "overwrite" deletes the
    run's files (``outputs``) and starts afresh. Without either, a UsageError names the
    folder and both choices: nothing is lost by a command run twice. ``inputs``
    ({option: paths}) are the files the command reads: --overwrite refuses to delete one."""
    from .config import UsageError
    folder = check_output(folder, option, folder=True)
    held = [name for name in RUN_MARKS if (folder / name).is_file()]
    if not held:
        if existing == "resume":
            print(f"--resume: no run in {str(folder)!r} yet; starting it", file=sys.stderr)
        return False
    if existing is None:
        raise UsageError(f"{option}: {str(folder)!r} holds a run ({', '.join(held)}); give "
                         f"--resume to continue it or --overwrite to start it afresh")
    if existing == "overwrite":
        deleted = {(folder / name).resolve() for name in outputs}
        read = [(name, p) for name, paths in (inputs or {}).items() for p in paths
                if p and Path(p).resolve() in deleted]
        if read:
            name, path = read[0]
            raise UsageError(f"{name}: {str(path)!r} is a file of the run in {str(folder)!r}, "
                             f"which --overwrite would delete; copy it elsewhere first")
        for name in outputs:
            (folder / name).unlink(missing_ok=True)
        return False
    if "checkpoint.npz" not in held:
        raise UsageError(f"--resume: {str(folder)!r} holds no checkpoint.npz to continue "
                         f"from; give --overwrite to start the run afresh")
    return True


def reason(error: Exception) -> str:
    """Why a file could not be read, in words (a KeyError names what is missing)."""
    text = str(error.args[0]) if error.args else type(error).__name__
    return f"no {text!r} in it" if isinstance(error, KeyError) and " " not in text else text


class DamagedCheckpoint(ValueError):
    """A checkpoint that ``--resume`` cannot continue; the CLI prints it as one line."""


@contextmanager
def reading_checkpoint(path):
    """Around restoring a run from the checkpoint ``path``: an array or a value that is
    missing or does not fit becomes a ``DamagedCheckpoint`` naming the file."""
    try:
        yield
    except (AttributeError, KeyError, TypeError, ValueError) as e:
        raise DamagedCheckpoint(f"--resume: {str(path)!r} cannot be continued ({reason(e)}); "
                                f"give --overwrite to start the run afresh") from None


# -- Ctrl-C in a training loop ----------------------------------------------------------
class RunStopped(KeyboardInterrupt):
    """Ctrl-C stopped a training loop at the end of a step, after it saved its
    checkpoint; the message says how far the run got and where its checkpoint is."""


class StopRequest:
    """``with StopRequest() as stop:`` around a training loop: Ctrl-C (SIGINT) sets
    ``stop.requested`` instead of interrupting, so the loop ends its step, saves its
    checkpoint and raises ``RunStopped``; a second Ctrl-C interrupts at once. Outside
    the main thread (no signal handler can be set there) Ctrl-C interrupts as usual."""

    def __init__(self):
        self.requested = False
        self._old = self._installed = None

    def _handle(self, signum, frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self) -> "StopRequest":
        self._installed = threading.current_thread() is threading.main_thread()
        if self._installed:
            self._old = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc) -> bool:
        if self._installed:     # None: a handler set outside Python; Python's own then
            signal.signal(signal.SIGINT, self._old if self._old is not None
                          else signal.default_int_handler)
        return False


# The shipped model files (minid3rqn/models), found from any working directory.
MODELS = Path(__file__).resolve().parent / "models"
