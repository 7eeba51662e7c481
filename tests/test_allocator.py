"""keep_freed_memory: the C allocator keeps NumPy's freed temporaries for the next call."""
import platform
import subprocess
import sys
import textwrap

import pytest

from minid3rqn.allocator import keep_freed_memory

# 64-bit glibc takes the default sizes (a 32-bit one caps the mmap threshold lower).
GLIBC = (platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"
         and sys.maxsize > 2 ** 32)

# A fresh child process (so that neither the setting nor the count depends on what other
# tests did) casts 256 poses a few times to warm up, then counts the page faults of ten
# more casts.
CHILD = textwrap.dedent("""
    import resource, sys
    import numpy as np
    from minid3rqn.allocator import keep_freed_memory
    from minid3rqn.world import Camera, make_scene, sample_start_pose
    from minid3rqn.world.renderer import cast_columns
    applied = keep_freed_memory() if sys.argv[1] == "keep" else False
    scene = make_scene("basic", 0)
    rng = np.random.default_rng(0)
    poses = np.stack([sample_start_pose(scene, rng) for _ in range(256)])
    batch, xn = scene.batch(), Camera().column_rays()
    for _ in range(3):
        cast_columns(batch, poses, xn)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(10):
        cast_columns(batch, poses, xn)
    after = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    print(applied, (after - before) / 10)
""")


def faults_per_cast(mode: str) -> tuple[bool, float]:
    done = subprocess.run([sys.executable, "-c", CHILD, mode], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    applied, faults = done.stdout.split()
    return applied == "True", float(faults)


@pytest.mark.world
@pytest.mark.skipif(not GLIBC, reason="mallopt is glibc's (64-bit); elsewhere the call does nothing")
def test_kept_memory_is_reused_without_page_faults():
    # A 256-pose cast makes several MB of temporaries per call (~2000 pages). Kept, they
    # come back from the heap already mapped: (almost) no page is faulted in again.
    applied, faults = faults_per_cast("keep")
    assert applied
    assert faults < 50, f"{faults} page faults per cast with the memory kept"


@pytest.mark.world
def test_returns_whether_it_applied():
    assert keep_freed_memory() is GLIBC
    assert keep_freed_memory() is GLIBC               # again: the same, no harm


@pytest.mark.parametrize("value, applied", [("1", False), ("yes", False), ("0", GLIBC),
                                              ("", GLIBC)])
def test_the_environment_can_opt_out(monkeypatch, value, applied):
    monkeypatch.setenv("MINID3RQN_DEFAULT_MALLOC", value)
    assert keep_freed_memory() is applied


@pytest.mark.parametrize("kwargs, name", [({"trim_bytes": 0}, "trim_bytes"),
                                          ({"mmap_bytes": -1}, "mmap_bytes"),
                                          ({"trim_bytes": 2 ** 31}, "trim_bytes"),
                                          ({"mmap_bytes": 1.5e6}, "mmap_bytes"),
                                          ({"trim_bytes": True}, "trim_bytes")])
def test_bad_sizes_are_refused_by_name(kwargs, name):
    with pytest.raises(ValueError, match=name):
        keep_freed_memory(**kwargs)
