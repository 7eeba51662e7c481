"""The plane-sweep cost volume and the DispNet that reads it (train-depth --cost-volume;
ours): depth from the motion between the frame and the one before."""
from pathlib import Path

import numpy as np
import pytest

from minid3rqn.depth import commands
from minid3rqn.depth.cost_volume import plane_sweep_cost, sweep_depths
from minid3rqn.depth.data import Sequence, collect
from minid3rqn.depth.evaluate import DepthEstimator, evaluate
from minid3rqn.depth.train import TrainConfig, Trainer
from minid3rqn.nets.dispnet import DispNet
from minid3rqn.world import Camera
from minid3rqn.world.geometry import inverse_warp_numpy, relative_transform

pytestmark = pytest.mark.depth
TINY = Camera(16, 24, 90.0)
ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def seq():
    data = collect("basic", n_frames=24, frames_per_flight=12, seed=5, camera=TINY,
                   progress=False)
    return Sequence(data["rgb"], data["flight"], data["K"], data["depth"], data["pose"])


def _motion(rng, n):
    """Random planar motions T_{t->t-1}: a step back of about 0.8 m and a small yaw."""
    now = np.zeros((n, 3))
    before = np.stack([-0.8 + 0.1 * rng.standard_normal(n), 0.1 * rng.standard_normal(n),
                       0.2 * rng.standard_normal(n)], axis=1)
    return relative_transform(now, before)


def _cfg(**kw):
    return TrainConfig(iterations=2, batch_size=2, lr=2e-3, seed=0, encoder=(8, 16),
                       decoder=(8, 8), n_scales=2, checkpoint_every=2, log_every=1, **kw)


def test_sweep_depths_are_even_in_inverse_depth():
    d = sweep_depths(5, 0.5, 10.0)
    assert d[0] == pytest.approx(0.5) and d[-1] == pytest.approx(10.0)
    np.testing.assert_allclose(np.diff(1 / d), np.full(4, (0.1 - 2.0) / 4))
    with pytest.raises(ValueError, match="n_planes"):
        sweep_depths(1)
    with pytest.raises(ValueError, match="near < far"):
        sweep_depths(4, 3.0, 2.0)


def test_the_cost_is_the_warp_of_the_previous_frame_at_each_depth(seq):
    """Each plane k equals |brightness - the previous frame's brightness warped with the
    constant depth d_k| (the world's warp, border padding), for arbitrary motions."""
    rng = np.random.default_rng(0)
    frame, prev = seq.rgb[1:5], seq.rgb[0:4]
    T, depths = _motion(rng, 4), sweep_depths(6)
    cost = plane_sweep_cost(frame, prev, T, seq.K, depths)
    assert cost.shape == (4, 16, 24, 6) and cost.dtype == np.float32
    bright = lambda a: a.astype(np.float64).mean(axis=-1)
    for k, d in enumerate(depths):
        warped, _ = inverse_warp_numpy(bright(prev), np.full((4, 16, 24), d), seq.K, T,
                                       padding="border")
        np.testing.assert_allclose(cost[..., k], np.abs(bright(frame) - warped) / 255,
                                   atol=2e-5)
    # chunking changes nothing
    np.testing.assert_array_equal(plane_sweep_cost(frame, prev, T, seq.K, depths, chunk=1),
                                  cost)


def test_the_lowest_cost_is_at_the_true_depth():
    """A frame that sees a textured wall at depth d_3 (made by warping a grey previous
    frame with that depth) has no cost at plane 3 wherever the warp stays inside the
    image, beyond rounding to uint8, and a larger one at the other planes on most
    pixels."""
    K = TINY.K
    rng = np.random.default_rng(1)
    grey = rng.integers(0, 256, (2, 16, 24), dtype=np.uint8)
    T, depths = _motion(rng, 2), sweep_depths(8)
    seen, inside = inverse_warp_numpy(grey.astype(np.float64), np.full((2, 16, 24), depths[3]),
                                      K, T)
    rgb = lambda g: np.repeat(np.round(g)[..., None], 3, axis=-1).astype(np.uint8)
    cost = plane_sweep_cost(rgb(seen), rgb(grey), T, K, depths)
    assert np.all(cost[..., 3][inside] <= 0.5 / 255 + 1e-6)
    assert np.mean(cost[inside].argmin(axis=-1) == 3) > 0.9


def test_mirroring_frames_and_motion_mirrors_the_cost(seq):
    """A mirrored pair of frames with the mirrored motion (M T M, M = diag(-1, 1, 1, 1))
    gives the mirrored cost volume: why the flip augmentation and the test-time flip of
    a cost-volume DispNet are consistent."""
    rng = np.random.default_rng(2)
    frame, prev, T = seq.rgb[1:4], seq.rgb[0:3], _motion(rng, 3)
    M = np.diag([-1.0, 1.0, 1.0, 1.0])
    a = plane_sweep_cost(frame, prev, T, seq.K)
    b = plane_sweep_cost(np.ascontiguousarray(frame[:, :, ::-1]),
                         np.ascontiguousarray(prev[:, :, ::-1]), M @ T @ M, seq.K)
    np.testing.assert_allclose(b, a[:, :, ::-1], atol=1e-5)


def test_bad_input_is_named(seq):
    frame, T = seq.rgb[1:3], np.tile(np.eye(4), (2, 1, 1))
    with pytest.raises(ValueError, match="frame must be uint8"):
        plane_sweep_cost(frame.astype(np.float32), frame, T, seq.K)
    with pytest.raises(ValueError, match="prev must have frame's shape"):
        plane_sweep_cost(frame, seq.rgb[1:4], T, seq.K)
    with pytest.raises(ValueError, match="T_to_prev must be finite"):
        plane_sweep_cost(frame, frame, T[:1], seq.K)
    with pytest.raises(ValueError, match="depths must be"):
        plane_sweep_cost(frame, frame, T, seq.K, depths=[1.0, -2.0])
    with pytest.raises(ValueError, match="K does not match"):
        plane_sweep_cost(frame, frame, T, Camera().K)
    with pytest.raises(ValueError, match="cost_planes must be an int"):
        DispNet(cost_planes=-1)


def test_a_one_frame_model_widened_predicts_what_it_did(seq, tmp_path):
    one = Trainer(seq, _cfg())
    meta = {"height": 16, "width": 24, "K": seq.K.tolist()}
    path = DepthEstimator(one.disp, 2.0, meta).save(tmp_path / "one.npz")
    cv = Trainer(seq, _cfg(cost_volume=4))
    cv.init_from(path)
    assert cv.disp.enc_a[0].weight.shape[1] == 3 + 4
    est1, est2 = DepthEstimator.load(path), DepthEstimator(cv.disp, 2.0, meta)
    assert est2.needs_previous and est2.cost_planes == 4 and not est1.needs_previous
    idx = est2.sequence_targets(seq)
    np.testing.assert_allclose(est2.predict_sequence(seq, idx), est1.predict(seq.rgb[idx]),
                               rtol=1e-5)
    # the fast path and the autograd forward agree on the cost-volume input
    motion = est2.sequence_motion(seq, idx)
    np.testing.assert_allclose(
        est2.predict_disp(seq.rgb[idx], prev=seq.rgb[idx - 1], motion=motion),
        est2.predict_disp_autograd(seq.rgb[idx], prev=seq.rgb[idx - 1], motion=motion),
        rtol=1e-4, atol=1e-6)
    assert evaluate(est2, seq)["prev_kernel_ratio"] == 0.0
    back = DepthEstimator.load(est2.save(tmp_path / "cv.npz"))
    assert back.cost_planes == 4
    np.testing.assert_allclose(back.predict_sequence(seq, idx), est1.predict(seq.rgb[idx]),
                               rtol=1e-5)
    rgb = seq.rgb[idx[:2]]
    with pytest.raises(ValueError, match="give prev"):
        back.predict(rgb)
    with pytest.raises(ValueError, match="give motion"):
        back.predict(rgb, prev=rgb)
    with pytest.raises(ValueError, match="reads one frame"):
        est1.predict(rgb, prev=rgb, motion=motion[:2])
    with pytest.raises(ValueError, match="no intrinsics"):
        DepthEstimator(cv.disp, 2.0, {"height": 16, "width": 24}).predict(
            rgb, prev=rgb, motion=motion[:2])


def test_training_builds_the_cost_volume_with_the_flights_motion(seq):
    tr = Trainer(seq, _cfg(cost_volume=4, flip=False))
    target, sources, _ = tr.sample_batch()
    idx, _ = tr._last
    x = tr.disp_input(target, sources)
    assert x.shape[1] == 3 + 4
    T = relative_transform(seq.pose[idx], seq.pose[idx - 1])
    expect = plane_sweep_cost(seq.rgb[idx], seq.rgb[idx - 1], T, seq.K, sweep_depths(4))
    np.testing.assert_allclose(x[:, 3:], expect.transpose(0, 3, 1, 2))
    # with a mirrored triplet: the cost volume of the mirrored frames and motion
    tr = Trainer(seq, _cfg(cost_volume=4))
    for _ in range(5):
        target, sources, _ = tr.sample_batch()
        idx, flip = tr._last
        if flip.any():
            break
    x = tr.disp_input(target, sources)
    k = int(np.flatnonzero(flip)[0])
    mirrored = plane_sweep_cost(seq.rgb[idx[k:k + 1]], seq.rgb[idx[k:k + 1] - 1],
                                relative_transform(seq.pose[idx[k:k + 1]],
                                                   seq.pose[idx[k:k + 1] - 1]),
                                seq.K, sweep_depths(4))[:, :, ::-1]
    np.testing.assert_allclose(x[k:k + 1, 3:], mirrored.transpose(0, 3, 1, 2), atol=1e-5)
    tr.run(progress=False)
    with pytest.raises(ValueError, match="source offsets must include -1"):
        Trainer(seq, _cfg(cost_volume=4, source_offsets=(1, 2)))


def test_train_depth_cost_volume_smoke(tmp_path):
    data = tmp_path / "train.npz"
    assert commands.main(["collect", "--frames", "20", "--frames-per-flight", "10",
                          "--out", str(data)]) == 0
    run = tmp_path / "run"
    assert commands.main(["train-depth", "--smoke", "--quiet", "--cost-volume", "4",
                          "--dir", str(run)]) == 0
    est = DepthEstimator.load(run / "model.npz")
    assert est.cost_planes == 4 and est.K.shape == (3, 3)
    assert commands.main(["eval-depth", "--model", str(run / "model.npz"), "--test-data",
                          str(run / "test.npz")]) == 0
