"""Files on disk: ``.npz`` written atomically, read without pickle; JSON lines
appended whole.

Atomic: the arrays go to a temporary file in the same folder, which is then renamed
over the target; a crash mid-write leaves the old file intact, never half a file. A
temporary file left by a writer that was killed is removed by the next write to the
same path. Files get the usual permissions (0666 less the umask), as ``open`` gives.
"""
from __future__ import annotations

import json
import os
import tempfile
import zipfile
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
                         f"written by minid3rqn): {e}") from None


def append_jsonl(path, record: dict) -> None:
    """Append ``record`` as one JSON line to ``path``, whole or not at all.

    The line is written with one ``write``; if that fails (a full disk), the file is cut
    back to its old length, so a results log never holds half a record. A log whose last
    line is incomplete is refused rather than extended."""
    path = Path(path)
    line = (json.dumps(record) + "\n").encode()
    with open(path, "ab+") as f:
        size = f.seek(0, os.SEEK_END)
        if size:
            f.seek(size - 1)
            if f.read(1) != b"\n":
                raise ValueError(f"{str(path)!r}: its last line is incomplete; repair the "
                                 f"file before appending to it")
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
    commands record this name in their model files (docs/beyond.md, "Determinism across
    machines").
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


# The shipped model files (minid3rqn/models), found from any working directory.
MODELS = Path(__file__).resolve().parent / "models"
