"""Frames of a Q-net's own flights (rl/flown_frames.py, ``collect --pilot``)."""
from pathlib import Path

import numpy as np
import pytest

from minid3rqn.depth import commands
from minid3rqn.depth.data import load_sequence
from minid3rqn.nets.qnet import QNet, QNetConfig
from minid3rqn.rl.flown_frames import collect_flown
from minid3rqn.rl.policies import QNetPolicy, StraightPolicy
from minid3rqn.world import Camera, render_batch
from minid3rqn.world.distance import nearest_distance

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "minid3rqn" / "models" / "d3rqn_basic.npz"


def _pilot(epsilon=0.3):
    return QNetPolicy(QNet(QNetConfig(width=8), rng=0), epsilon=epsilon)


def test_flown_frames_are_one_action_apart_and_seeded():
    kw = dict(n_frames=60, seed=3, depth="gt", max_steps=9, chunk=4, progress=False)
    data = collect_flown(_pilot(), **kw)
    assert 58 <= len(data["rgb"]) <= 60
    assert data["rgb"].dtype == np.uint8 and data["depth"].shape == data["rgb"].shape[:3]
    flight = data["flight"]
    assert np.all(np.diff(flight) >= 0) and np.all(np.diff(flight) <= 1)
    counts = np.bincount(flight)
    assert counts.min() >= 3 and counts.max() <= 10           # max_steps + 1 frames
    same = flight[1:] == flight[:-1]
    step = np.hypot(*np.diff(data["pose"][:, :2], axis=0).T)[same]
    # one action: 0.4 s at 2 m/s along an arc, so a chord of at most 0.8 m
    assert np.all(step <= 0.8 + 1e-9) and np.all(step > 0.79)
    # the same seed flies the same frames (the random actions are drawn per chunk)
    again = collect_flown(_pilot(), **kw)
    for key in ("rgb", "depth", "pose", "flight"):
        np.testing.assert_array_equal(data[key], again[key])
    other = collect_flown(_pilot(), **{**kw, "seed": 4})
    assert not np.array_equal(other["pose"][:10], data["pose"][:10])


def test_a_flight_ends_before_the_step_that_came_too_close():
    data = collect_flown(StraightPolicy(), n_frames=300, seed=0, depth="gt", max_steps=49,
                         chunk=8, progress=False)
    counts = np.bincount(data["flight"])
    short = np.flatnonzero(counts[:-1] < 50)          # the last flight may be cut to fit
    assert len(short) > 0, "flying straight, some flight must hit something"
    # the rendered GT depth is the world's view from the stored pose
    k = int(short[0])
    rows = np.flatnonzero(data["flight"] == k)
    assert counts[k] >= 3
    # every step between two frames was flown safely; the flight ended because its
    # next step (not filmed: it can end at, or in, an obstacle) came within 0.5 m
    world = _scene_of(data, k)
    rgb, depth = render_batch(world, data["pose"][rows], Camera())
    np.testing.assert_allclose(depth, data["depth"][rows], rtol=1e-5)
    np.testing.assert_array_equal(rgb, data["rgb"][rows])
    xy = data["pose"][rows, :2]
    s = np.linspace(0.0, 1.0, 9)[:, None]
    clear = [nearest_distance(world, a + s * (b - a)).min() for a, b in zip(xy[:-1], xy[1:])]
    assert min(clear) >= 0.5
    ahead = xy[-1] + s * 0.8 * np.array([np.cos(data["pose"][rows[-1], 2]),
                                         np.sin(data["pose"][rows[-1], 2])])
    assert nearest_distance(world, ahead).min() < 0.5      # flying straight on: too close


def _scene_of(data, k):
    """The scene a flight flew in: the one whose GT depth matches its first frame."""
    from minid3rqn.rl.evaluate import _chunk_seeds
    from minid3rqn.rl.flights import Flights, FlightsConfig
    first = data["pose"][data["flight"] == k][0]
    for n, child in _chunk_seeds(0, 8 * 101, 8):
        fl = Flights("basic", n, seed=child, config=FlightsConfig(n_worlds=8),
                     autoreset=False)
        for w in fl.worlds:
            _, d = render_batch(w, first[None], Camera())
            if np.allclose(d, data["depth"][data["flight"] == k][:1], rtol=1e-5):
                assert nearest_distance(w, first[None, :2]).min() >= 0.5
                return w
    raise AssertionError("no world of the collection matches the flight's first frame")


def test_collect_pilot_command(tmp_path, capsys):
    out = tmp_path / "flown.npz"
    assert commands.main(["collect", "--pilot", str(SHIPPED), "--pilot-depth", "gt",
                          "--frames", "30", "--frames-per-flight", "10", "--seed", "1",
                          "--out", str(out)]) == 0
    assert "frames in" in capsys.readouterr().out
    seq = load_sequence(out)
    assert 28 <= len(seq) <= 30 and len(seq.triplet_indices()) > 0
    from minid3rqn.io import load_npz
    _, meta = load_npz(out)
    assert meta["pilot"] == str(SHIPPED) and meta["pilot_depth"] == "gt"
    assert "--pilot" in meta["command"]


@pytest.mark.parametrize("argv, named", [
    (["--pilot", "no_such_net.npz"], "--pilot"),
    (["--pilot", str(SHIPPED), "--late-turns", "0.5"], "--late-turns"),
    (["--pilot", str(SHIPPED), "--crab-deg", "10"], "--crab-deg"),
    (["--pilot", str(SHIPPED), "--pilot-epsilon", "1.5"], "--pilot-epsilon"),
    (["--pilot", str(SHIPPED), "--frames-per-flight", "2"], "--frames-per-flight"),
])
def test_collect_pilot_refuses_bad_options_by_name(tmp_path, argv, named):
    with pytest.raises(SystemExit, match=named):
        commands.main(["collect", "--pilot-depth", "gt", "--frames", "10",
                       "--out", str(tmp_path / "x.npz")] + argv)


def test_collect_flown_rejects_bad_counts():
    for kw, named in ((dict(n_frames=2), "n_frames"), (dict(max_steps=1), "max_steps"),
                      (dict(chunk=0), "chunk")):
        with pytest.raises(ValueError, match=named):
            collect_flown(_pilot(), depth="gt", progress=False, **kw)
