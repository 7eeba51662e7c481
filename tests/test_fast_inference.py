"""The graph-free inference paths (nets/fast.py: ConvInference, DispNetInference,
qnet_step) against the autograd forward they replace at inference time.

Training always runs the autograd path; ``DepthEstimator.predict`` runs the inference
path. These tests pin the two together: on random weights and inputs (float64 and
float32, several shapes, odd sizes that crop in the decoder, batches larger than the
chunk) and on the shipped depth model with rendered frames.
"""
from pathlib import Path

import numpy as np
import pytest

from minid3rqn import autograd as ag
from minid3rqn.depth.evaluate import DepthEstimator
from minid3rqn.depth.flip import FlipAveraged
from minid3rqn.nets.dispnet import DispNet
from minid3rqn.nets.fast import (ConvInference, DispNetInference, bias_elu_, qnet_step,
                                 upsample_conv_phases)
from minid3rqn.nets.layers import Conv2d

SHIPPED = Path(__file__).resolve().parents[1] / "minid3rqn" / "models" / "depth_basic.npz"


def _nhwc_padded(x: np.ndarray, p: int) -> np.ndarray:
    """NCHW -> zero-padded channels-last, as the inference path keeps activations."""
    xp = np.pad(x, ((0, 0), (0, 0), (p, p), (p, p)))
    return np.ascontiguousarray(xp.transpose(0, 2, 3, 1))


def _autograd_disp(net: DispNet, rgb_nhwc: np.ndarray) -> np.ndarray:
    with ag.no_grad():
        x = np.ascontiguousarray(rgb_nhwc.transpose(0, 3, 1, 2))
        return net(x, scales=1)[0].data[:, 0]


def _random_net(dtype, seed=0, **kw) -> DispNet:
    """A DispNet with random weights, biases spread so that ELUs see both signs."""
    net = DispNet(rng=seed, **kw)
    rng = np.random.default_rng(seed + 100)
    for p in net.parameters():
        if p.ndim == 1:
            p.data[...] = rng.normal(scale=0.3, size=p.shape)
    return net.astype(dtype)


# -- single layers -------------------------------------------------------------------------
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("c_in, c_out, k, stride, pad", [
    (3, 16, 3, 2, 1), (16, 16, 3, 1, 1), (32, 8, 4, 2, 0), (5, 7, 1, 1, 0), (6, 4, 3, 1, 2),
    (64, 96, 3, 2, 1)])
def test_conv_inference_is_the_autograd_conv_to_the_bit(dtype, c_in, c_out, k, stride, pad):
    """Same routine (conv2d_nhwc), same operands: identical numbers, not just close."""
    rng = np.random.default_rng(1)
    conv = Conv2d(c_in, c_out, k, stride=stride, padding=pad, rng=2, dtype=dtype)
    x = rng.normal(size=(3, c_in, 11, 17)).astype(dtype)
    fast = ConvInference(conv)
    assert not fast.contract_first
    got = fast(_nhwc_padded(x, pad)).transpose(0, 3, 1, 2)
    np.testing.assert_array_equal(got, ag.conv2d(x, conv.weight, None, stride, pad).data)
    with_bias = got + fast.bias[:, None, None]
    np.testing.assert_array_equal(with_bias, ag.conv2d(x, conv.weight, conv.bias, stride,
                                                       pad).data)


@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-12), (np.float32, 1e-5)])
def test_conv_inference_contract_first_for_few_outputs(dtype, tol):
    """A 1-channel head (KH*KW*C_out <= C_in) contracts channels first: equal to round-off."""
    rng = np.random.default_rng(3)
    conv = Conv2d(16, 1, 3, padding=1, rng=4, dtype=dtype)
    fast = ConvInference(conv)
    assert fast.contract_first
    x = rng.normal(size=(2, 16, 9, 13)).astype(dtype)
    got = fast(_nhwc_padded(x, 1)).transpose(0, 3, 1, 2)
    ref = ag.conv2d(x, conv.weight, None, 1, 1).data
    np.testing.assert_allclose(got, ref, rtol=tol, atol=tol)


def test_bound_conv_reads_its_buffers_afresh_each_call():
    rng = np.random.default_rng(5)
    for c_out in (8, 1):                                  # im2col and contract-first
        conv = Conv2d(12, c_out, 3, padding=1, rng=6, dtype=np.float64)
        fast = ConvInference(conv)
        xp = np.zeros((2, 7, 9, 12))
        out = np.empty((2, 5, 7, c_out))
        run = fast.bind(xp, out, np.empty(fast.work_size(xp)))
        for _ in range(2):
            x = rng.normal(size=(2, 12, 5, 7))
            xp[:, 1:-1, 1:-1] = x.transpose(0, 2, 3, 1)
            run()
            np.testing.assert_allclose(out.transpose(0, 3, 1, 2),
                                       ag.conv2d(x, conv.weight, None, 1, 1).data, rtol=1e-12,
                                       atol=1e-12)


@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-12), (np.float32, 1e-5)])
def test_upsample_conv_phases_equal_conv_of_the_upsampled_image(dtype, tol):
    rng = np.random.default_rng(7)
    x = rng.normal(size=(2, 5, 4, 6)).astype(dtype)
    w = rng.normal(size=(3, 5, 3, 3)).astype(dtype)
    ref = ag.conv2d(ag.upsample(x, 2, "nearest"), w, None, 1, 1).data      # (2, 3, 8, 12)
    xp = _nhwc_padded(x, 1)
    for (p, q), wpq in upsample_conv_phases(w).items():
        got = ConvInference.of(wpq)(xp[:, p:p + 5, q:q + 7])                # (2, 4, 6, 3)
        np.testing.assert_allclose(got.transpose(0, 3, 1, 2), ref[:, :, p::2, q::2],
                                   rtol=tol, atol=tol)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_bias_elu_is_ag_elu_to_round_off(dtype):
    """``bias_elu_`` computes e^x - 1 with ``exp`` where ``ag.elu`` uses ``expm1`` (SIMD
    on every CPU; its docstring): the positive side must be ``ag.elu``'s to the bit,
    the negative side within two units of 1.0's last place, absolute, of the exact ELU
    (float64) and of ``ag.elu``; and it must really be an ELU (bias added, saturating
    at -1)."""
    rng = np.random.default_rng(8)
    y = np.concatenate([rng.normal(scale=3, size=5000),
                        [0.0, -0.0, -1e-30, 1e-30, -100.0, 50.0, -1e-3]]).astype(dtype)
    tiny = -np.logspace(-30, 2, 2000).astype(dtype)        # negatives of every size
    eps = np.finfo(dtype).eps
    for y, b in ((y, dtype(0.25)), (tiny, None)):
        x = y if b is None else y + b
        ref = ag.elu(x).data
        got = bias_elu_(y.copy(), b, np.empty_like(y), np.zeros_like(y))
        assert got.dtype == dtype
        pos = x > 0
        np.testing.assert_array_equal(got[pos], ref[pos])
        x64 = x.astype(np.float64)
        exact = np.where(pos, x64, np.expm1(np.minimum(x64, 0.0)))
        assert np.abs(got - exact).max() <= 2 * eps
        assert np.abs(got - ref).max() <= 2 * eps
        assert got.min() >= -1.0 and got[x < -40].max() == -1.0


# -- the whole network -----------------------------------------------------------------
@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-11), (np.float32, 2e-5)])
@pytest.mark.parametrize("kw, hw", [
    ({}, (32, 104)),                                                    # the shipped shape
    ({"encoder": (8, 12, 16), "decoder": (6, 8, 10), "n_scales": 2}, (20, 36)),  # crops
    ({"encoder": (8, 12), "decoder": (4, 8), "n_scales": 1}, (15, 22)),
    ({"encoder": (8, 12, 16, 24), "decoder": (8, 8, 12, 16), "init_disp": None}, (13, 9))])
def test_dispnet_inference_equals_the_autograd_forward(dtype, tol, kw, hw):
    net = _random_net(dtype, **kw)
    rng = np.random.default_rng(9)
    rgb = rng.random((5,) + hw + (3,)).astype(dtype)
    ref = _autograd_disp(net, rgb)
    fast = DispNetInference(net, chunk=2)                 # 3 chunks: 2, 2, 1 frames
    for _ in range(2):                                    # buffers reused on the 2nd call
        got = fast(rgb)
        assert got.shape == ref.shape and got.dtype == dtype
        np.testing.assert_allclose(got, ref, rtol=tol, atol=0)
    np.testing.assert_allclose(fast(rgb[3:4]), ref[3:4], rtol=tol, atol=0)   # batch 1


def test_dispnet_inference_takes_uint8_like_the_estimator():
    net = _random_net(np.float32, encoder=(8, 12), decoder=(4, 8), n_scales=2)
    rgb = np.random.default_rng(10).integers(0, 256, (3, 16, 24, 3), dtype=np.uint8)
    ref = _autograd_disp(net, rgb.astype(np.float32) * (1 / 255.0))
    np.testing.assert_allclose(DispNetInference(net)(rgb), ref, rtol=2e-5, atol=0)


def test_inference_is_a_snapshot_and_a_new_estimator_rereads_weights():
    net = _random_net(np.float32, encoder=(8, 12), decoder=(4, 8), n_scales=2)
    est = DepthEstimator(net, 2.0, {"height": 16, "width": 24})
    rgb = np.random.default_rng(11).integers(0, 256, (2, 16, 24, 3), dtype=np.uint8)
    before = est.predict(rgb)
    net.heads[0].bias.data += 1.0                         # e.g. a training step
    np.testing.assert_array_equal(est.predict(rgb), before)
    est = DepthEstimator(net, 2.0, {"height": 16, "width": 24})
    after = est.predict(rgb)
    assert not np.allclose(after, before)
    ref = _autograd_disp(net, rgb.astype(np.float32) * (1 / 255.0))
    np.testing.assert_allclose(after, est.scale / ref, rtol=2e-5)


def test_flip_averages_the_mirrored_prediction_and_is_mirror_equivariant():
    net = _random_net(np.float32, encoder=(8, 12), decoder=(4, 8), n_scales=2)
    plain = DepthEstimator(net, 2.0, {"height": 16, "width": 24})
    flip = FlipAveraged(DepthEstimator(net, 2.0, {"height": 16, "width": 24}))
    rgb = np.random.default_rng(12).integers(0, 256, (3, 16, 24, 3), dtype=np.uint8)
    mirrored = np.ascontiguousarray(rgb[:, :, ::-1])
    want = 0.5 * (plain.predict_disp(rgb) + plain.predict_disp(mirrored)[:, :, ::-1])
    np.testing.assert_allclose(flip.predict_disp(rgb), want, rtol=1e-6)
    assert not np.allclose(flip.predict_disp(rgb), plain.predict_disp(rgb))
    # A mirrored world gives the mirrored depth map (exactly, up to float32 round-off),
    # whatever the network: the point of averaging the two views.
    np.testing.assert_allclose(flip.predict(mirrored), flip.predict(rgb)[:, :, ::-1],
                               rtol=1e-6)
    # One frame alone: the same, to the round-off of a different batch size.
    np.testing.assert_allclose(flip.predict(rgb[1]), flip.predict(rgb)[1], rtol=1e-4)


def test_the_flip_wraps_a_loaded_estimator_and_keeps_its_scale(tmp_path):
    from minid3rqn.rl.models import load_depth_estimator
    net = _random_net(np.float32, encoder=(8, 12), decoder=(4, 8), n_scales=2)
    path = DepthEstimator(net, 2.0, {"height": 16, "width": 24}).save(tmp_path / "m.npz")
    plain, flip = load_depth_estimator(path), load_depth_estimator(path, flip=True)
    assert isinstance(plain, DepthEstimator) and isinstance(flip, FlipAveraged)
    assert flip.scale == plain.scale == 2.0 and flip.meta == plain.meta


# -- the shipped model on rendered frames ------------------------------------------------
@pytest.mark.skipif(not SHIPPED.exists(), reason="no shipped depth model")
def test_shipped_model_predict_matches_the_autograd_path():
    from minid3rqn.depth.data import collect
    rgb = collect("basic", n_frames=24, frames_per_flight=8, seed=3, progress=False)["rgb"]
    est = DepthEstimator.load(SHIPPED)
    ref = est.scale / _autograd_disp(est.net, rgb.astype(np.float32) * (1 / 255.0))
    for frames in (rgb, rgb[:1], rgb[5]):                 # batched, batch 1, one (H, W, 3)
        depth = est.predict(frames)
        want = ref[:len(frames)] if frames.ndim == 4 else ref[5]
        assert depth.dtype == np.float32 and depth.shape == want.shape
        assert np.max(np.abs(depth - want) / want) < 1e-4
    assert np.max(np.abs(est.predict(rgb) - ref) / ref) < 1e-5


# -- the Q-network's acting step -----------------------------------------------------------
@pytest.mark.parametrize("variant, channels", [("d3rqn", 1), ("ddrqn", 1), ("d3qn", 5),
                                               ("ddqn", 5)])
def test_qnet_step_without_graph_equals_forward(variant, channels):
    """Under no_grad qnet_step runs on plain arrays; same Q and state, to the bit."""
    from minid3rqn.nets.qnet import QNet, QNetConfig
    net = QNet(QNetConfig.for_variant(variant, in_channels=channels), rng=0)
    rng = np.random.default_rng(12)
    for batch in (1, 3):
        obs = rng.random((batch, channels, 32, 104)).astype(np.float32)
        state = None
        if net.recurrent:
            state = tuple(ag.Tensor(rng.normal(size=(batch, 128)).astype(np.float32))
                          for _ in range(2))
        q_ref, state_ref = net.step(obs, state)           # gradients on: forward
        with ag.no_grad():
            q, new_state = qnet_step(net, obs, state)
        np.testing.assert_array_equal(q.data, q_ref.data)
        if net.recurrent:
            for a, b in zip(new_state, state_ref):
                np.testing.assert_array_equal(a.data, b.data)
        else:
            assert new_state is None and state_ref is None


def test_qnet_step_without_graph_reads_the_current_weights():
    from minid3rqn.nets.qnet import QNet, QNetConfig
    net = QNet(QNetConfig.for_variant("d3rqn"), rng=0)
    obs = np.random.default_rng(13).random((2, 1, 32, 104)).astype(np.float32)
    with ag.no_grad():
        before = qnet_step(net, obs)[0].data.copy()
        net.value.bias.data += 1.0                        # e.g. an optimizer step
        np.testing.assert_allclose(qnet_step(net, obs)[0].data, before + 1.0, rtol=1e-6)
