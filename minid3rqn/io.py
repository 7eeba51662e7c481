"""Files on disk: every file written atomically through one function (``write_file``),
``.npz`` read without pickle; JSON lines appended whole; one writer per run folder or
output file (``hold``); run folders and output paths checked before a command works; a
training loop stopped by Ctrl-C at the end of a step.

Atomic: the bytes go to a temporary file in the same folder, which is flushed to disk
and then renamed over the target; a crash or a full disk mid-write leaves the old file
whole, never half a file. A failed write raises ``WriteError``, naming the file and the
reason. A temporary file left by a writer that was killed is removed by the next write
to the same path. Files get the usual permissions (0666 less the umask), as ``open``
gives.

Paths: an output that is a symbolic link is written through to the file it points to
(the link stays a link; a dangling link makes its target); a path in a loop of links,
or a name that is not UTF-8 text (it could not be recorded in a model file or printed),
is refused in one line.
"""
from __future__ import annotations

import errno
import json
import os
import shlex
import signal
import sys
import tempfile
import threading
import zipfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .config import UsageError


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


class WriteError(OSError):
    """A file could not be written (a full disk, a read-only folder...): the message names
    the file and the reason, and says that the earlier file, if any, is whole."""

    def __str__(self) -> str:
        return self.strerror


def _fill(f, content) -> None:
    """Write ``content`` (bytes, text, or a function of a binary file) to the file ``f``."""
    if callable(content):
        content(f)
    else:
        f.write(content.encode() if isinstance(content, str) else content)


def write_file(path, content) -> Path:
    """The one way minid3rqn writes a file: ``content`` (bytes, text written as UTF-8, or
    a function that writes to a binary file object) goes to a temporary file beside
    ``path``, flushed to disk, then renamed over ``path``. A symbolic link is written
    through to its target. If anything fails the temporary file is removed and the file
    at ``path`` is as it was; an OSError becomes a ``WriteError`` naming ``path``."""
    shown = Path(path)
    path = _target(shown)
    _remove_stale_temporaries(path)
    existed = path.is_file()
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f"{path.name}.{os.getpid()}.",
                                   suffix=".tmp")
        os.chmod(tmp, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as f:
            _fill(f, content)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        tmp = None
    except OSError as e:
        kept = "the earlier file is kept whole" if existed else "nothing was written"
        raise WriteError(e.errno, f"could not write {str(shown)!r}: "
                                  f"{e.strerror or e}; {kept}") from None
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.remove(tmp)
    return shown


def write_json(path, value, indent: int | None = 2) -> Path:
    """``value`` as a JSON file (``write_file``), ending in a newline."""
    return write_file(path, json.dumps(value, indent=indent) + "\n")


def write_image(path, image, **options) -> Path:
    """A Pillow image (or uint8 array) as a file whose format its suffix names
    (``write_file``); ``options`` go to ``Image.save`` (a GIF's frames, ...)."""
    from PIL import Image
    if not isinstance(image, Image.Image):
        image = Image.fromarray(np.asarray(image))
    kind = {".png": "PNG", ".gif": "GIF", ".jpg": "JPEG", ".jpeg": "JPEG"}.get(
        Path(path).suffix.lower(), "PNG")
    return write_file(path, lambda f: image.save(f, format=kind, **options))


def _target(path: Path) -> Path:
    """Where writing ``path`` lands: the file a symbolic link points to (followed to the
    end; a dangling link's target), else ``path``. OSError for a loop of links."""
    if not path.is_symlink():
        return path
    try:
        os.stat(path)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise WriteError(e.errno, f"could not write {str(path)!r}: it is in a loop of "
                                      f"symbolic links") from None
    return Path(os.path.realpath(path))


def save_npz(path, arrays: dict[str, np.ndarray], metadata: dict | None = None) -> Path:
    """Write ``arrays`` (and optional JSON-able ``metadata``) to ``path`` atomically."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"save_npz: path must end in .npz; got {str(path)!r}")
    payload = {k: np.asarray(v) for k, v in arrays.items()}
    if metadata is not None:
        if "__metadata__" in payload:
            raise ValueError("save_npz: the key '__metadata__' is reserved")
        payload["__metadata__"] = np.asarray(json.dumps(metadata))
    for key, value in payload.items():
        if value.dtype == object:
            raise TypeError(f"save_npz: array {key!r} has dtype object, which would need "
                            f"pickle; store numbers or strings only")
    return write_file(path, lambda f: np.savez(f, **payload))


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
    try:
        with open(path, "ab") as f:
            size = f.seek(0, os.SEEK_END)
            try:
                f.write(line)
                f.flush()
                os.fsync(f.fileno())
            except BaseException:
                f.truncate(size)
                raise
    except OSError as e:
        raise WriteError(e.errno, f"could not append to {str(path)!r}: {e.strerror or e}; "
                                  f"the file is as it was") from None


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
    problem = path_problem(path)
    if problem:
        raise UsageError(f"{option}: {problem}")
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


def path_problem(path) -> str | None:
    """Why ``path`` cannot name a file minid3rqn reads or writes, or None: a name that is
    not UTF-8 text (it could be neither printed nor recorded in a model file), or a path
    through a loop of symbolic links."""
    text = str(path)
    try:
        text.encode()
    except UnicodeEncodeError:
        return (f"{ascii(text)} is not a UTF-8 name (it could be neither printed nor "
                f"recorded); rename it")
    try:
        os.stat(text)
    except OSError as e:
        if e.errno == errno.ELOOP:
            return f"{text!r} is in a loop of symbolic links"
    return None


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


# -- one writer per run folder or output file -----------------------------------------
class Busy(UsageError):
    """Another command holds the lock of a run folder or output file (``hold``)."""


def _lock_folder() -> Path:
    """Where the locks live: one folder of the machine, so that a lock changes nothing in
    the folders a command is asked to write (sticky and writable by all, as /tmp is)."""
    folder = Path(tempfile.gettempdir()) / "minid3rqn-locks"
    if not folder.is_dir():
        folder.mkdir(exist_ok=True)
        try:
            os.chmod(folder, 0o1777)
        except OSError:
            pass
    return folder


def lock_path(target) -> Path:
    """The lock file of ``target`` (a run folder or an output file): named by a digest of
    its full path, symbolic links resolved, so two spellings of one target share it."""
    import hashlib
    where = str(Path(target).resolve())
    return _lock_folder() / (hashlib.sha1(where.encode("utf-8", "surrogateescape"))
                             .hexdigest()[:20] + ".lock")


def _holder(lock: Path) -> str:
    """Who holds ``lock``, in words, from what its holder wrote in it."""
    try:
        who = json.loads(lock.read_text())
        text = f"pid {who['pid']} ({who['command']}), since {who['since']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "another process"
    try:
        os.kill(int(who["pid"]), 0)
    except ProcessLookupError:       # its lock lives on in processes it started
        text += "; it has ended, but processes it started still run"
    except (OSError, ValueError, TypeError):
        pass
    return text


def _flock(fd: int) -> bool:
    """Take the exclusive lock of the open file ``fd`` without waiting; False if held.
    The operating system releases it when its holder ends, however it ends: a lock is
    never stale. (``fcntl.flock`` on POSIX, ``msvcrt.locking`` on Windows.)"""
    try:
        import fcntl
    except ImportError:                                      # Windows
        import msvcrt
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
            return True
        except OSError:
            return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False


@contextmanager
def hold(target, option: str):
    """``with hold(path, "--out"):`` around a command's work on a run folder or an output
    file: one writer at a time. A second command on the same target (while this one
    runs) gets a ``Busy`` naming ``option``, the target and the holder (its pid, its
    command and since when); a holder that died holds nothing (the lock is the operating
    system's, released with its process)."""
    import datetime
    lock = lock_path(target)
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        if not _flock(fd):
            os.close(fd)
            raise Busy(f"{option}: {str(target)!r} is in use by another command: "
                       f"{_holder(lock)}; wait for it to end, or choose another {option}")
        try:                                  # the file may have been removed meanwhile
            same = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    since = datetime.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M:%S %Z")
    words = "python -m minid3rqn " + shlex.join(sys.argv[1:])
    record = {"pid": os.getpid(), "command": words, "since": since,
              "target": str(Path(target).resolve())}
    os.ftruncate(fd, 0)
    os.write(fd, json.dumps(record, ensure_ascii=True).encode())
    try:
        yield Path(target)
    finally:
        try:
            os.unlink(lock)
        except OSError:
            pass
        os.close(fd)


@contextmanager
def holding(*targets):
    """``hold`` of every (path, option) in ``targets`` (None paths skipped; two spellings
    of one path held once), for a command that writes several outputs."""
    from contextlib import ExitStack
    with ExitStack() as stack:
        seen = set()
        for path, option in targets:
            if path is None or lock_path(path) in seen:
                continue
            seen.add(lock_path(path))
            stack.enter_context(hold(path, option))
        yield


def whole(path) -> bool:
    """Whether the file ``path`` reads whole as what its suffix says: an .npz every array
    of which loads, a JSON document, a PNG or GIF image, a text file ending in a newline.
    What a finished run's files are checked with before ``--resume`` calls it done."""
    path = Path(path)
    if not path.is_file():
        return False
    try:
        if path.suffix == ".npz":
            load_npz(path)
        elif path.suffix == ".json":
            json.loads(path.read_text())
        elif path.suffix in (".png", ".gif"):
            from PIL import Image
            with Image.open(path) as im:
                im.verify()
        else:
            data = path.read_bytes()
            return bool(data) and data.endswith(b"\n")
    except Exception:        # noqa: BLE001 - whatever the reader says: not whole
        return False
    return True


def reason(error: Exception) -> str:
    """Why a file could not be read, in words (a KeyError names what is missing)."""
    text = str(error.args[0]) if error.args else type(error).__name__
    return f"no {text!r} in it" if isinstance(error, KeyError) and " " not in text else text


class DamagedCheckpoint(ValueError):
    """A checkpoint that ``--resume`` cannot continue; the CLI prints it as one line."""


def check_checkpoint_weights(arrays: dict) -> None:
    """ValueError if a checkpoint's float arrays hold NaN or inf: such a file is damaged
    (a training that diverges stops before it saves), whatever its weights say."""
    for name, value in arrays.items():
        if value.dtype.kind == "f" and not np.isfinite(value).all():
            raise ValueError(f"its array {name!r} holds NaN or inf: the file is damaged (a "
                             f"training that diverges stops before it saves)")


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
