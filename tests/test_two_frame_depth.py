"""The two-frame DispNet (train-depth --prev-frame; ours): the frame and the one before."""
import argparse
from pathlib import Path

import numpy as np
import pytest

from minid3rqn.depth import commands
from minid3rqn.depth.data import Sequence, collect
from minid3rqn.depth.evaluate import DepthEstimator, evaluate
from minid3rqn.depth.train import TrainConfig, Trainer
from minid3rqn.nets.dispnet import DispNet
from minid3rqn.nets.fast import DispNetInference
from minid3rqn.rl.flights import Flights, FlightsConfig
from minid3rqn.world import Camera, render_batch

pytestmark = pytest.mark.depth
TINY = Camera(16, 24, 90.0)
ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "minid3rqn" / "models" / "depth_basic.npz"


@pytest.fixture(scope="module")
def seq():
    data = collect("basic", n_frames=24, frames_per_flight=12, seed=5, camera=TINY,
                   progress=False)
    return Sequence(data["rgb"], data["flight"], data["K"], data["depth"], data["pose"])


def _cfg(**kw):
    return TrainConfig(iterations=2, batch_size=2, lr=2e-3, seed=0, encoder=(8, 16),
                       decoder=(8, 8), n_scales=2, checkpoint_every=2, log_every=1, **kw)


def test_input_channels_and_the_fast_path():
    net = DispNet((8, 16), (8, 8), 2, rng=0, in_frames=2)
    x = np.random.default_rng(0).random((3, 6, 16, 24)).astype(np.float32)
    d = net(x, scales=1)[0].data[:, 0]
    fast = DispNetInference(net)(np.ascontiguousarray(x.transpose(0, 2, 3, 1)))
    np.testing.assert_allclose(fast, d, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match=r"\(N, 6, H, W\)"):
        net(x[:, :3])
    with pytest.raises(ValueError, match="in_frames must be 1 or 2"):
        DispNet(in_frames=3)


def test_a_one_frame_model_widened_predicts_what_it_did(seq, tmp_path):
    one = Trainer(seq, _cfg())
    size = {"height": 16, "width": 24}
    path = DepthEstimator(one.disp, 2.0, size).save(tmp_path / "one.npz")
    two = Trainer(seq, _cfg(prev_frame=True))
    two.init_from(path)
    est1, est2 = DepthEstimator.load(path), DepthEstimator(two.disp, 2.0, size)
    assert (est1.in_frames, est2.in_frames) == (1, 2)
    rgb = seq.rgb[5:9]
    noise = np.random.default_rng(1).integers(0, 256, rgb.shape, dtype=np.uint8)
    np.testing.assert_allclose(est2.predict(rgb, prev=noise), est1.predict(rgb), rtol=1e-5)
    # a network that ignores the previous frame is measured to ignore it
    from minid3rqn.depth.data import Sequence as Seq
    assert evaluate(est2, Seq(seq.rgb, seq.flight, seq.K, seq.depth, seq.pose)
                    )["prev_frame_effect"] < 1e-5
    assert evaluate(est2, seq)["prev_kernel_ratio"] == 0.0      # its kernels are zero
    # the file keeps the second frame
    back = DepthEstimator.load(est2.save(tmp_path / "two.npz"))
    assert back.in_frames == 2
    np.testing.assert_allclose(back.predict(rgb, prev=noise), est1.predict(rgb), rtol=1e-5)
    with pytest.raises(ValueError, match="give prev"):
        back.predict(rgb)
    with pytest.raises(ValueError, match="reads one frame"):
        est1.predict(rgb, prev=rgb)
    with pytest.raises(ValueError, match="prev must have"):
        back.predict(rgb, prev=rgb[:2])


def test_training_reads_the_previous_frame_and_is_scored_where_there_is_one(seq):
    tr = Trainer(seq, _cfg(prev_frame=True))
    target, sources = seq.batch(seq.triplet_indices()[:2])
    x = tr.disp_input(target, sources)
    assert x.shape[1] == 6
    np.testing.assert_array_equal(x[:, 3:], sources[0])       # offset -1: the frame before
    tr.run(progress=False)
    est = DepthEstimator(tr.disp, 1.0, {"height": 16, "width": 24})
    idx = est.sequence_targets(seq)
    assert len(idx) == len(seq) - (seq.flight.max() + 1)      # all but each flight's first
    assert np.all(seq.flight[idx - 1] == seq.flight[idx])
    assert evaluate(est, seq)["frames"] == len(idx)
    assert evaluate(est, seq)["prev_frame_effect"] >= 0
    one = DepthEstimator(Trainer(seq, _cfg()).disp, 1.0, {"height": 16, "width": 24})
    assert evaluate(one, seq)["frames"] == len(seq)
    assert evaluate(one, seq, with_previous=True)["frames"] == len(idx)
    with pytest.raises(ValueError, match="source offsets must include -1"):
        Trainer(seq, _cfg(prev_frame=True, source_offsets=(1, 2)))


def test_flights_hand_a_two_frame_model_the_frame_before(monkeypatch):
    net = DispNet((8, 16, 16, 16), (8, 8, 8, 8), 1, rng=0, in_frames=2)
    est = DepthEstimator(net, 2.0)
    seen = []
    real = est.predict

    def spy(rgb, batch_size=64, prev=None, motion=None):
        assert motion is None                       # motion is for a cost volume
        seen.append((rgb.copy(), prev.copy()))
        return real(rgb, batch_size, prev)

    monkeypatch.setattr(est, "predict", spy)
    fl = Flights("basic", 3, seed=0, config=FlightsConfig(n_worlds=3), depth="pred",
                 depth_estimator=est, autoreset=False)
    fl.reset()
    start = fl.poses.copy()
    rgb0, prev0 = seen[-1]
    # at the start: the view from 0.8 m back along the heading
    back = start.copy()
    back[:, 0] -= 0.8 * np.cos(start[:, 2])
    back[:, 1] -= 0.8 * np.sin(start[:, 2])
    expect, _ = render_batch(fl.batch, back, fl.camera)
    np.testing.assert_array_equal(prev0, expect)
    fl.step(np.zeros(3, np.int64))
    rgb1, prev1 = seen[-1]
    np.testing.assert_array_equal(prev1, rgb0)                 # then: the last frame seen


def test_train_depth_prev_frame_smoke(tmp_path, capsys):
    data = tmp_path / "train.npz"
    assert commands.main(["collect", "--frames", "20", "--frames-per-flight", "10",
                          "--out", str(data)]) == 0
    run = tmp_path / "run"
    assert commands.main(["train-depth", "--smoke", "--quiet", "--prev-frame",
                          "--dir", str(run)]) == 0
    est = DepthEstimator.load(run / "model.npz")
    assert est.in_frames == 2
    assert commands.main(["eval-depth", "--model", str(run / "model.npz"), "--test-data",
                          str(run / "test.npz"), "--by-depth"]) == 0
    assert commands.main(["eval-depth", "--model", str(run / "model.npz"), "--test-data",
                          str(run / "test.npz"), "--with-previous"]) == 0
    assert "GT depth (m)" in capsys.readouterr().out
