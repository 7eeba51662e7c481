"""Unsupervised depth: geometry, the view-synthesis loss, data, training, evaluation."""
import json

import numpy as np
import pytest

from minid3rqn import autograd as ag
from minid3rqn.autograd import Tensor
from minid3rqn.depth.data import Sequence, collect, load_sequence, save_sequence, triplet_indices
from minid3rqn.depth.evaluate import DepthEstimator, depth_metrics, errors_by_depth, evaluate
from minid3rqn.depth.geometry import (check_intrinsics, inverse_warp, matrix_to_pose_vec,
                                      pose_vec_to_mat)
from minid3rqn.depth.losses import (LossConfig, l1_error, photometric_error,
                                    reconstruction_errors, view_synthesis_loss)
from minid3rqn.depth.train import TrainConfig, Trainer
from minid3rqn.world import Camera
from minid3rqn.world.geometry import inverse_warp_numpy, relative_transform

pytestmark = pytest.mark.depth

TINY = Camera(16, 24, 90.0)


def _k(h, w, f=None):
    f = f or w / 2
    return np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])


@pytest.fixture(scope="module")
def flight():
    """Three consecutive frames of one scripted flight in the basic world."""
    data = collect("basic", n_frames=3, frames_per_flight=3, seed=3, progress=False)
    return data


@pytest.fixture(scope="module")
def tiny_sequence():
    data = collect("basic", n_frames=24, frames_per_flight=12, seed=5, camera=TINY,
                   progress=False)
    return Sequence(data["rgb"], data["flight"], data["K"], data["depth"], data["pose"])


# -- geometry ------------------------------------------------------------------------------
def test_pose_vec_round_trip_and_rigid():
    rng = np.random.default_rng(0)
    vec = rng.normal(scale=0.3, size=(5, 6))
    T = pose_vec_to_mat(vec).data
    R = T[:, :3, :3]
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.allclose(T[:, 3], [0, 0, 0, 1])
    assert np.allclose(matrix_to_pose_vec(T), vec, atol=1e-12)


@pytest.fixture(scope="module")
def flight_raised():
    """The same, filmed by a camera with its horizon at row 4 (Camera.horizon_row)."""
    return collect("basic", n_frames=3, frames_per_flight=3, seed=3, progress=False,
                   camera=Camera(horizon_row=4))


@pytest.mark.parametrize("padding", ["zeros", "border"])
@pytest.mark.parametrize("which", ["middle", "raised-horizon"])
def test_warp_with_gt_reconstructs_target_and_matches_world(flight, flight_raised, which,
                                                            padding):
    """GT depth of the middle frame + GT relative pose: the autograd warp of each
    neighbour reproduces the middle frame, and equals the world's NumPy warp; with the
    horizon in the middle row and raised (an off-centre principal point)."""
    flight = flight if which == "middle" else flight_raised
    rgb, depth, pose, K = flight["rgb"], flight["depth"], flight["pose"], flight["K"]
    assert K[1, 2] == (15.5 if which == "middle" else 4.0)
    tgt = rgb[1].astype(np.float64) / 255
    for s in (0, 2):
        T = relative_transform(pose[1], pose[s])
        src = rgb[s].astype(np.float64) / 255
        ref, ref_valid = inverse_warp_numpy(src, depth[1], K, T, padding)
        src_t = Tensor(src.transpose(2, 0, 1)[None].copy(), requires_grad=True)
        depth_t = Tensor(depth[1][None, None].astype(np.float64), requires_grad=True)
        T_t = Tensor(T[None].copy(), requires_grad=True)
        out, valid = inverse_warp(src_t, depth_t, T_t, K, padding)
        np.testing.assert_allclose(out.data[0].transpose(1, 2, 0), ref, atol=1e-9)
        np.testing.assert_array_equal(valid[0, 0].astype(bool), ref_valid)
        v = ref_valid
        assert v.mean() > 0.5
        err_warp = np.abs(out.data[0].transpose(1, 2, 0) - tgt)[v].mean()
        err_identity = np.abs(src - tgt)[v].mean()
        assert err_warp < 0.03 and err_warp < 0.5 * err_identity
        # every input is reached by the gradient
        (out * out).sum().backward()
        for t in (src_t, depth_t, T_t):
            assert t.grad is not None and np.isfinite(t.grad).all() and np.abs(t.grad).sum() > 0


def test_mismatched_intrinsics_raise():
    with pytest.raises(ValueError, match="does not match the image size"):
        check_intrinsics(_k(32, 104), 16, 52)
    raised = Camera(horizon_row=4)                 # a horizon off the middle row is fine,
    np.testing.assert_array_equal(check_intrinsics(raised.K, 32, 104), raised.K)
    with pytest.raises(ValueError, match="does not match the image size"):
        check_intrinsics(raised.K, 4, 104)         # a horizon outside the image is not
    with pytest.raises(ValueError, match="does not match the image size"):
        inverse_warp(np.zeros((1, 3, 8, 12)), np.ones((1, 8, 12)), np.eye(4)[None],
                     _k(16, 24))


# -- the loss ------------------------------------------------------------------------------
@pytest.mark.parametrize("cfg", [LossConfig(), LossConfig(ssim_weight=0.0, full_res=True,
                                                          unmasked_weight=0.1)],
                         ids=["default", "l1-full-res-unmasked"])
def test_gradcheck_view_synthesis_loss(cfg):
    rng = np.random.default_rng(1)
    h, w, n = 4, 8, 1
    K = _k(h, w)
    target = rng.random((n, 3, h, w))
    sources = [rng.random((n, 3, h, w)) for _ in range(2)]
    disp0 = rng.uniform(0.3, 0.6, (n, 1, h, w))
    disp1 = rng.uniform(0.3, 0.6, (n, 1, h // 2, w // 2))
    poses = rng.normal(scale=0.05, size=(n, 2, 6))

    def fn(d0, d1, p):
        loss, _ = view_synthesis_loss(target, sources, [d0, d1], p, K, cfg)
        return loss

    assert ag.gradcheck(fn, [disp0, disp1, poses], atol=1e-5, rtol=1e-4)


def test_gradcheck_the_papers_loss():
    """Eq. 2: L_vs = sum_s sum_p |I_t(p) - Î_s(p)|, the sum of reconstruction_errors with
    the L1 error; its gradient in depth and pose checks against central differences."""
    rng = np.random.default_rng(1)
    h, w, n = 4, 8, 1
    K = _k(h, w)
    target = rng.random((n, 3, h, w))
    sources = [rng.random((n, 3, h, w)) for _ in range(2)]
    depth = rng.uniform(1.5, 3.0, (n, 1, h, w))
    poses = rng.normal(scale=0.05, size=(2 * n, 6))

    def paper_loss(d, p):
        errors, _ = reconstruction_errors(target, sources, d, pose_vec_to_mat(p), K)
        return ag.sum(errors)

    assert ag.gradcheck(paper_loss, [depth, poses], atol=1e-5, rtol=1e-4)
    errors, valid = reconstruction_errors(target, sources, Tensor(depth),
                                          pose_vec_to_mat(Tensor(poses)), K, l1_error)
    assert errors.shape == valid.shape == (2, n, 1, h, w)


def test_loss_prefers_the_true_depth_and_pose(flight):
    """With GT pose, GT depth beats a constant depth, infinite depth and no motion."""
    from minid3rqn.depth.losses import downsample_image
    rgb, depth, pose, K = flight["rgb"], flight["depth"], flight["pose"], flight["K"]
    f = lambda i: rgb[i].transpose(2, 0, 1)[None].astype(np.float32) / 255
    target, sources = f(1), [f(0), f(2)]
    vec = np.stack([matrix_to_pose_vec(relative_transform(pose[1], pose[s]))
                    for s in (0, 2)])[None].astype(np.float32)

    def loss(d, p):
        d = d[None, None].astype(np.float32)
        disps = [Tensor(1 / downsample_image(d, 2 ** i)) for i in range(4)]
        return float(view_synthesis_loss(target, sources, disps, Tensor(p), K)[0].data)

    best = loss(depth[1], vec)
    for d, p in [(np.full_like(depth[1], 4.0), vec), (np.full_like(depth[1], 90.0), vec),
                 (depth[1], 0 * vec)]:
        assert best < 0.8 * loss(d, p)


def test_posenet_forward_init():
    from minid3rqn.nets.posenet import PoseNet
    x = np.random.default_rng(0).random((2, 3, 16, 24)).astype(np.float32)
    net = PoseNet(pose_scale=0.1, head_gain=0.0, init_tz=(0.8, -0.8))
    out = net(x, [x, x]).data
    assert out.shape == (2, 2, 6)
    np.testing.assert_allclose(out[:, :, 2], [[0.8, -0.8]] * 2, rtol=1e-5)
    assert np.all(out[:, :, [0, 1, 3, 4, 5]] == 0)
    with pytest.raises(ValueError, match="init_tz"):
        PoseNet(init_tz=(0.8,))


def test_photometric_error_is_zero_for_equal_images():
    x = np.random.default_rng(0).random((2, 3, 8, 12)).astype(np.float32)
    assert np.abs(photometric_error(x, x).data).max() < 1e-5
    y = np.random.default_rng(1).random((2, 3, 8, 12)).astype(np.float32)
    np.testing.assert_array_equal(photometric_error(x, y, ssim_weight=0.0).data,
                                  l1_error(x, y).data)         # alpha = 0: the paper's L1


def test_the_photometric_error_is_a_parameter(tiny_sequence):
    """A photometric error given to the loss (and the Trainer) replaces the configured
    one: the classroom's exercise passes the student's this way."""
    calls = []

    def squared(pred, target):
        calls.append(pred.shape)
        return ag.mean((pred - target) * (pred - target), axis=1, keepdims=True)
    trainer = Trainer(tiny_sequence, _tiny_cfg(1), photometric_error=squared)
    trainer.run(progress=False)
    assert calls and all(c[1] == 3 for c in calls)
    rng = np.random.default_rng(0)
    img = rng.random((1, 3, 8, 16)).astype(np.float32)
    disps = [Tensor(np.full((1, 1, 8, 16), 0.5, np.float32))]
    poses = np.zeros((1, 2, 6), np.float32)
    plain, _ = view_synthesis_loss(img, [img, img], disps, poses, _k(8, 16))
    l1, _ = view_synthesis_loss(img, [img, img], disps, poses, _k(8, 16),
                                photometric_error=l1_error)
    assert float(plain.data) == pytest.approx(float(l1.data))   # no motion, no error


# -- data ------------------------------------------------------------------------------------
def test_triplets_never_cross_flights(tiny_sequence):
    seq = tiny_sequence
    idx = seq.triplet_indices()
    assert len(idx) == len(seq) - 2 * (seq.flight.max() + 1)
    for t in idx:
        assert seq.flight[t - 1] == seq.flight[t] == seq.flight[t + 1]
    boundary = int(np.flatnonzero(np.diff(seq.flight))[0]) + 1      # first frame of flight 1
    with pytest.raises(ValueError, match="other flights"):
        seq.batch(np.array([boundary]))
    with pytest.raises(IndexError, match="inside the sequence"):
        seq.batch(np.array([0]))
    assert triplet_indices([0, 0, 1, 1, 1]).tolist() == [3]
    assert triplet_indices([0, 0]).tolist() == []


def test_bad_sequences_raise(tiny_sequence):
    seq = tiny_sequence
    with pytest.raises(ValueError, match="empty"):
        Sequence(seq.rgb[:0], seq.flight[:0], seq.K)
    with pytest.raises(ValueError, match="does not match the image size"):
        Sequence(seq.rgb, seq.flight, _k(32, 104))
    with pytest.raises(ValueError, match="consecutive"):
        Sequence(seq.rgb[:3], np.array([0, 1, 0]), seq.K)
    with pytest.raises(ValueError, match="no triplet"):
        Trainer(Sequence(seq.rgb[:2], seq.flight[:2], seq.K), _tiny_cfg(1))


def test_sequence_file_round_trip(tiny_sequence, tmp_path):
    seq = tiny_sequence
    path = save_sequence(tmp_path / "s.npz", {"rgb": seq.rgb, "depth": seq.depth,
                                              "pose": seq.pose, "flight": seq.flight,
                                              "K": seq.K}, {"scenario": "basic"})
    back = load_sequence(path)
    np.testing.assert_array_equal(back.rgb, seq.rgb)
    assert back.meta["scenario"] == "basic"


# -- training --------------------------------------------------------------------------------
def _tiny_cfg(iterations, **kw):
    return TrainConfig(iterations=iterations, batch_size=2, lr=2e-3, seed=0,
                       checkpoint_every=2, log_every=1, **kw)


def test_training_lowers_the_loss(tiny_sequence):
    trainer = Trainer(tiny_sequence, _tiny_cfg(12))
    fixed = np.array(tiny_sequence.triplet_indices()[:4])
    target, sources = tiny_sequence.batch(fixed)

    def loss_now():
        with ag.no_grad():
            disps = trainer.disp(target)
            poses = trainer.pose(target, sources)
            return float(view_synthesis_loss(target, sources, disps, poses,
                                             tiny_sequence.K, trainer.cfg.loss)[0].data)

    before = loss_now()
    trainer.sample_batch = lambda: (target, sources)                   # overfit one batch
    trainer.run(progress=False)
    assert loss_now() < 0.9 * before


def test_resume_continues_exactly(tiny_sequence, tmp_path):
    ckpt = tmp_path / "ckpt.npz"
    Trainer(tiny_sequence, _tiny_cfg(2), checkpoint=ckpt).run(progress=False)
    resumed = Trainer(tiny_sequence, _tiny_cfg(4), checkpoint=ckpt, resume=True)
    assert resumed.iteration == 2
    resumed.run(progress=False)
    straight = Trainer(tiny_sequence, _tiny_cfg(4))
    straight.run(progress=False)
    for a, b in zip(resumed.params, straight.params):
        np.testing.assert_array_equal(a.data, b.data)
    assert [r["loss"] for r in resumed.history] == [r["loss"] for r in straight.history]
    other = _tiny_cfg(4)
    other.lr = 1e-4
    with pytest.raises(ValueError, match="lr"):
        Trainer(tiny_sequence, other, checkpoint=ckpt, resume=True)


def test_fine_tune_starts_from_a_checkpoint_or_a_shipped_model_file(tiny_sequence, tmp_path):
    """init_from takes a training checkpoint (DispNet + PoseNet) or a DepthEstimator file
    (DispNet only; PoseNet keeps its own fresh initialisation)."""
    ckpt = tmp_path / "ckpt.npz"
    source = Trainer(tiny_sequence, _tiny_cfg(2), checkpoint=ckpt)
    source.run(progress=False)
    model = DepthEstimator(source.disp, 1.0).save(tmp_path / "model.npz")
    fresh_pose = Trainer(tiny_sequence, _tiny_cfg(2)).pose
    for path, pose_from in ((ckpt, source.pose), (model, fresh_pose)):
        tuned = Trainer(tiny_sequence, _tiny_cfg(2))
        tuned.init_from(path)
        for a, b in zip(tuned.disp.parameters(), source.disp.parameters()):
            np.testing.assert_array_equal(a.data, b.data)
        for a, b in zip(tuned.pose.parameters(), pose_from.parameters()):
            np.testing.assert_array_equal(a.data, b.data)
        assert tuned.iteration == 0


def test_nan_loss_names_the_iteration(tiny_sequence):
    trainer = Trainer(tiny_sequence, _tiny_cfg(3))
    trainer.disp.heads[0].bias.data[:] = np.nan
    with pytest.raises(FloatingPointError, match="NaN.*iteration 1"):
        trainer.run(progress=False)


# -- evaluation and inference ---------------------------------------------------------------
def test_metrics_of_a_perfect_and_a_scaled_prediction():
    gt = np.random.default_rng(0).uniform(1, 10, (3, 8, 12))
    m = depth_metrics(3.7 * gt, gt)                      # median scaling removes the scale
    assert m["abs_rel"] < 1e-12 and m["a1"] == 1.0
    m = depth_metrics(3.7 * gt, gt, median_scaling=False)
    assert m["abs_rel"] > 1


def test_a_frame_without_valid_pixels_is_left_out_not_a_nan():
    rng = np.random.default_rng(0)
    gt = rng.uniform(1, 10, (3, 8, 12))
    pred = gt * rng.uniform(0.8, 1.25, gt.shape)
    wall = gt.copy()
    wall[1] = 0.05                     # a camera against a wall: no GT depth over 0.1 m
    m = depth_metrics(pred, wall)
    assert all(np.isfinite(v) for v in m.values())
    assert m == depth_metrics(pred[[0, 2]], gt[[0, 2]])
    assert all(np.isfinite(r["share"]) for r in errors_by_depth(pred, wall))
    with pytest.raises(ValueError, match="no pixel has a GT depth"):
        depth_metrics(pred, np.full_like(gt, 0.05))


def test_estimator_round_trip_and_shapes(tiny_sequence, tmp_path):
    trainer = Trainer(tiny_sequence, _tiny_cfg(1))
    est = DepthEstimator(trainer.disp, 2.5, {"height": 16, "width": 24})
    path = est.save(tmp_path / "m.npz", {"seed": 0})
    back = DepthEstimator.load(path)
    rgb = tiny_sequence.rgb[:3]
    depth = back.predict(rgb)
    assert depth.shape == (3, 16, 24) and depth.dtype == np.float32
    np.testing.assert_allclose(depth, est.predict(rgb), rtol=1e-6)
    with pytest.raises(ValueError, match="trained on 16x24"):
        back.predict(np.zeros((1, 32, 104, 3), np.uint8))
    r = evaluate(back, tiny_sequence, posenet=trainer.pose)
    assert 0 <= r["a1"] <= 1 and r["rot_err_deg"] >= 0


# -- options: the gyro's yaw, the lr step; the smoothness and speed terms -------------------
def test_gradcheck_smoothness():
    from minid3rqn.depth.losses import smoothness_loss
    rng = np.random.default_rng(2)
    image = rng.random((2, 3, 5, 7))
    assert ag.gradcheck(lambda d: smoothness_loss(d, image),
                        [rng.uniform(0.2, 0.8, (2, 1, 5, 7))], atol=1e-6, rtol=1e-4)


def test_speed_term_is_zero_at_the_known_step():
    from minid3rqn.depth.losses import speed_loss
    poses = np.zeros((1, 2, 6), np.float32)
    poses[0, :, 2] = [0.8, -0.8]
    assert float(speed_loss(Tensor(poses), 0.8).data) == pytest.approx(0.0, abs=1e-6)
    assert float(speed_loss(Tensor(poses), 0.4).data) == pytest.approx(0.4, abs=1e-6)


def test_the_flights_motion_mirrors_with_the_flip(tiny_sequence):
    """The motion the gyro reads agrees with the images, flipped or not: with GT depth
    the warp of a flipped triplet is as good as that of the unflipped one."""
    from minid3rqn.world.geometry import inverse_warp_numpy
    trainer = Trainer(tiny_sequence, _tiny_cfg(1))
    idx = tiny_sequence.triplet_indices()[:3]
    errors = {}
    for flipped in (False, True):
        T = trainer.motion(idx, 1, np.full(len(idx), flipped))
        img = lambda i: tiny_sequence.rgb[i][:, :, ::-1] if flipped else tiny_sequence.rgb[i]
        depth = tiny_sequence.depth[idx][:, :, ::-1] if flipped else tiny_sequence.depth[idx]
        warped, valid = inverse_warp_numpy(img(idx + 1), depth, tiny_sequence.K, T)
        errors[flipped] = np.abs(warped - img(idx).astype(float))[valid].mean()
    identity = np.abs(tiny_sequence.rgb[idx + 1].astype(float) - tiny_sequence.rgb[idx]).mean()
    assert errors[False] < 0.6 * identity      # the GT warp redraws the target
    assert errors[True] < 1.5 * errors[False]  # (a wrongly mirrored pose gives ~3x)


def test_lr_steps_down_at_lr_decay_at(tiny_sequence):
    cfg = _tiny_cfg(3)
    cfg.lr_decay_at = 2
    trainer = Trainer(tiny_sequence, cfg)
    lrs = []
    for _ in range(3):
        lrs.append(trainer.current_lr())
        trainer.step()
    assert lrs == [cfg.lr, cfg.lr, pytest.approx(0.1 * cfg.lr)]


def test_the_gyro_reads_the_true_yaw(tiny_sequence, monkeypatch):
    """The simulated gyro reports ry of T_{t->s} (index 4, about the camera's vertical
    axis, by far the largest rotation of a flight), plus its noise."""
    import minid3rqn.depth.train as train_module
    trainer = Trainer(tiny_sequence, _tiny_cfg(1))
    idx, flip = tiny_sequence.triplet_indices()[:4], np.zeros(4, bool)
    vec = np.stack([matrix_to_pose_vec(trainer.motion(idx, o, flip)) for o in (-1, 1)], 1)
    assert np.abs(vec[..., 4]).max() > 10 * np.abs(vec[..., [3, 5]]).max()
    noisy = trainer.gyro_yaws(idx, flip)
    assert 0 < np.abs(noisy - vec[..., 4]).max() < 5 * train_module.GYRO_NOISE
    monkeypatch.setattr(train_module, "GYRO_NOISE", 0.0)
    np.testing.assert_allclose(trainer.gyro_yaws(idx, flip), vec[..., 4], atol=1e-6)


def test_gyro_yaw_mode_warps_with_the_gyro(tiny_sequence, monkeypatch):
    """gyro_yaw: the pose the loss sees has the gyro's yaw (PoseNet's is unused)."""
    import minid3rqn.depth.train as train_module
    monkeypatch.setattr(train_module, "GYRO_NOISE", 0.0)
    trainer = Trainer(tiny_sequence, _tiny_cfg(1, gyro_yaw=True))
    seen = {}
    real = train_module.view_synthesis_loss

    def spy(target, sources, disps, poses, *args):
        seen["poses"] = poses.data.copy()
        return real(target, sources, disps, poses, *args)

    monkeypatch.setattr(train_module, "view_synthesis_loss", spy)
    trainer.step()
    idx, flip = trainer._last
    truth = np.stack([matrix_to_pose_vec(trainer.motion(idx, o, flip))[..., 4]
                      for o in (-1, 1)], 1)
    np.testing.assert_allclose(seen["poses"][..., 4], truth, atol=1e-6)


def test_errors_by_depth_locates_a_biased_band():
    from minid3rqn.depth.evaluate import errors_by_depth
    gt = np.tile(np.linspace(1.0, 20.0, 40), (3, 8, 1))
    pred = np.where(gt < 2.0, 1.5 * gt, gt)          # near pixels 50 % too far
    rows = errors_by_depth(pred, gt)
    near = rows[0]
    assert near["signed_rel"] > 0.3 and near["abs_rel"] > 0.3
    assert all(abs(r["signed_rel"]) < 0.05 for r in rows[1:])
    assert sum(r["share"] for r in rows) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="pred"):
        errors_by_depth(pred[:1], gt)


def test_metrics_in_the_models_own_metric_scale():
    """A prediction 20 % too far everywhere: median scaling hides it, the model's own
    scale shows it; errors_by_depth aligns as depth_metrics does."""
    from minid3rqn.depth.evaluate import align_to_gt, errors_by_depth
    gt = np.tile(np.linspace(1.0, 20.0, 40), (2, 6, 1))
    pred = 1.2 * gt
    assert all(abs(r["signed_rel"]) < 1e-9 for r in errors_by_depth(pred, gt))
    assert depth_metrics(pred, gt)["abs_rel"] == pytest.approx(0.0, abs=1e-12)
    assert depth_metrics(pred, gt, median_scaling=False)["abs_rel"] == pytest.approx(0.2)
    p, g, ok = align_to_gt(pred, gt, median_scaling=False)
    np.testing.assert_allclose(p[ok], pred[ok])
    with pytest.raises(ValueError, match="errors_by_depth.*same"):
        errors_by_depth(pred[0], gt[0])


def test_collect_stops_when_the_remainder_cannot_make_a_triplet():
    """A flight that ends early can leave 1-2 frames to collect; no flight that short can
    hold a triplet, so collect stops there instead of trying fresh worlds for ever."""
    from minid3rqn.world import Camera
    data = collect("channel", n_frames=8, frames_per_flight=3, seed=1000, progress=False,
                   camera=Camera(8, 16, 90.0))
    assert 6 <= len(data["rgb"]) <= 8
    assert np.all(np.bincount(data["flight"]) >= 3)


def test_late_turning_pilot_shows_more_obstacles_close_ahead():
    """The late turner flies at obstacles and swerves late, so more of its frames show an
    obstacle under 2 m in the middle of the view than the careful pilot's; the careful
    pilot (late = 0) is the default."""
    from minid3rqn.world import Camera
    cam = Camera(16, 52, 90.0)

    def close_ahead(late):
        d = collect("basic", n_frames=300, seed=3, progress=False, camera=cam, late=late)
        centre = d["depth"][:, 4:12, 20:32].min(axis=(1, 2))
        return (centre < 2.0).mean()

    careful = close_ahead(0.0)
    assert close_ahead(1.0) > careful + 0.03
    plain = collect("basic", n_frames=30, seed=3, progress=False, camera=cam)
    np.testing.assert_array_equal(
        plain["pose"], collect("basic", n_frames=30, seed=3, progress=False, camera=cam,
                               late=0.0)["pose"])
    with pytest.raises(ValueError, match="late"):
        collect("basic", n_frames=30, seed=3, progress=False, camera=cam, late=1.5)


def test_collect_config_checks_its_values():
    """CollectConfig validates once, naming the field; held_out gives the other worlds."""
    from minid3rqn.config import ConfigError
    from minid3rqn.depth.data import CollectConfig, held_out
    for bad in (dict(frames=2), dict(late_turns=1.5), dict(scenario="moon"),
                dict(frames_per_flight=1)):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            CollectConfig(**bad)
    test = held_out(CollectConfig(scenario="channel", seed=3, late_turns=0.5), 40)
    assert (test.scenario, test.frames, test.seed, test.late_turns) == ("channel", 40, 1003, 0)


def test_train_config_checks_its_values():
    from minid3rqn.config import ConfigError
    for bad in (dict(iterations=0), dict(batch_size=0), dict(lr=0.0), dict(lr=float("nan")),
                dict(init_disp=20.0), dict(lr_decay_at=0), dict(loss={"ssim_weight": 1.5}),
                dict(loss={"unmasked_weight": -1.0})):
        with pytest.raises(ConfigError):
            TrainConfig(**bad)
    assert TrainConfig(loss={"full_res": True}).loss == LossConfig(full_res=True)


# -- the shipped depth models -----------------------------------------------------------------
MODELS = __import__("pathlib").Path(__file__).resolve().parent.parent / "minid3rqn" / "models"


@pytest.mark.parametrize("scenario", ["basic", "channel", "intersections", "corners"])
def test_shipped_depth_models_load_and_predict_metric_depth(scenario):
    """Each shipped DispNet has its JSON (command, seed, results) and predicts depth in
    metres on frames of its own scenario: median within a factor 1.5 of the truth."""
    path = MODELS / f"depth_{scenario}.npz"
    if not path.exists():
        pytest.skip(f"no shipped depth model for {scenario}")
    meta = json.loads(path.with_suffix(".json").read_text())
    assert {"command", "seed", "results"} <= set(meta) and scenario in meta["command"]
    est = DepthEstimator.load(path)
    data = collect(scenario, n_frames=6, frames_per_flight=6, seed=11, progress=False)
    depth = est.predict(data["rgb"])
    assert depth.shape == data["depth"].shape and np.isfinite(depth).all() and depth.min() > 0
    ratio = np.median(depth) / np.median(data["depth"])
    assert 1 / 1.5 < ratio < 1.5
