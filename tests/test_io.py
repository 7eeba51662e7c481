"""Files on disk: atomic .npz writes, readable errors, whole JSON lines, finite weights."""
import json
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from minid3rqn.io import append_jsonl, load_npz, save_npz
from minid3rqn.nets.module import Module
from minid3rqn.autograd import Tensor


def test_round_trip_and_permissions(tmp_path):
    path = save_npz(tmp_path / "a.npz", {"x": np.arange(3.0)}, {"kind": "test"})
    arrays, meta = load_npz(path)
    assert np.array_equal(arrays["x"], np.arange(3.0)) and meta == {"kind": "test"}
    mask = os.umask(0)
    os.umask(mask)
    assert os.stat(path).st_mode & 0o777 == 0o666 & ~mask


def test_truncated_file_and_folder_are_named(tmp_path):
    path = save_npz(tmp_path / "a.npz", {"x": np.zeros(1000)})
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="not a readable .npz"):
        load_npz(path)
    with pytest.raises(FileNotFoundError, match="is a folder"):
        load_npz(tmp_path)


def test_killed_writer_keeps_the_old_file_and_its_temporary_is_cleaned(tmp_path):
    """A child process killed in the middle of writing: the old file is intact, and the
    next write removes the temporary file the child left."""
    path = tmp_path / "big.npz"
    save_npz(path, {"x": np.ones(3)})
    code = textwrap.dedent(f"""
        import numpy as np, sys
        from minid3rqn import io
        real = np.savez
        def slow(f, **kw):
            f.write(b"partial")
            f.flush()
            print("writing", flush=True)
            import time; time.sleep(60)
        io.np.savez = slow
        io.save_npz({str(path)!r}, {{"x": np.zeros(3)}})
    """)
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert child.stdout.readline().strip() == "writing"
    child.send_signal(signal.SIGKILL)
    child.wait()
    assert len(list(tmp_path.glob("big.npz.*.tmp"))) == 1
    assert np.array_equal(load_npz(path)[0]["x"], np.ones(3))
    save_npz(path, {"x": np.full(3, 2.0)})
    assert list(tmp_path.glob("*.tmp")) == []
    assert np.array_equal(load_npz(path)[0]["x"], np.full(3, 2.0))


def test_append_jsonl_is_whole_or_nothing(tmp_path):
    path = tmp_path / "log.jsonl"
    append_jsonl(path, {"a": 1})
    append_jsonl(path, {"a": 2})
    assert [json.loads(x)["a"] for x in path.read_text().splitlines()] == [1, 2]
    with pytest.raises(TypeError):                 # not JSON-able: nothing written
        append_jsonl(path, {"a": object()})
    assert len(path.read_text().splitlines()) == 2
    with open(path, "a") as f:                     # half a record, as a full disk leaves
        f.write('{"a": 3')
    with pytest.raises(ValueError, match="last line is incomplete"):
        append_jsonl(path, {"a": 4})
    assert path.read_text().endswith('{"a": 3')


class _One(Module):
    def __init__(self):
        super().__init__()
        self.w = Tensor(np.zeros(2, np.float32), requires_grad=True)


def test_non_finite_weights_are_refused_on_load(tmp_path):
    net = _One()
    net.w.data[0] = np.nan
    path = net.save(tmp_path / "nan.npz")
    with pytest.raises(ValueError, match="NaN or inf"):
        _One().load(path)
