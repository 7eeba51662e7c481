"""Inference runs the forward a student reads: ``DispNet.forward`` and ``QNet.step``
under ``no_grad``, through the same kernels as training (autograd/kernels.py).

These tests pin what inference must keep: no graph under ``no_grad``; the same numbers
as the recorded forward (to the bit where the schedule is the same, to float round-off
where a kernel sums in another order); weights changed by an optimizer step or an
in-place update seen by the next prediction (the cached weight matrices follow
``Tensor.version``); reused buffers never leaking into outputs; and an edit of
``QNet.head`` changing what ``evaluate`` flies.
"""
from pathlib import Path

import numpy as np
import pytest

from minid3rqn import autograd as ag
from minid3rqn.autograd import kernels
from minid3rqn.autograd.optim import Adam
from minid3rqn.depth.evaluate import DepthEstimator
from minid3rqn.depth.flip import FlipAveraged
from minid3rqn.nets.dispnet import DispNet
from minid3rqn.nets.layers import Conv2d
from minid3rqn.nets.qnet import QNet, QNetConfig

SHIPPED = Path(__file__).resolve().parents[1] / "minid3rqn" / "models" / "depth_basic.npz"
SHIPPED_Q = SHIPPED.parent / "d3rqn_basic.npz"


def _autograd_disp(net: DispNet, rgb_nhwc: np.ndarray) -> np.ndarray:
    """The finest disparity with the graph on (what training differentiates)."""
    x = np.ascontiguousarray(rgb_nhwc.transpose(0, 3, 1, 2))
    return net(x, scales=1)[0].data[:, 0]


def _random_net(dtype, seed=0, **kw) -> DispNet:
    """A DispNet with random weights, biases spread so that ELUs see both signs."""
    net = DispNet(rng=seed, **kw)
    rng = np.random.default_rng(seed + 100)
    for p in net.parameters():
        if p.ndim == 1:
            p.set_(rng.normal(scale=0.3, size=p.shape))
    return net.astype(dtype)


# -- single layers -------------------------------------------------------------------------
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("c_in, c_out, k, stride, pad", [
    (3, 16, 3, 2, 1), (16, 16, 3, 1, 1), (32, 8, 4, 2, 0), (5, 7, 1, 1, 0), (6, 4, 3, 1, 2),
    (64, 96, 3, 2, 1)])
def test_conv_without_graph_is_the_recorded_conv_to_the_bit(dtype, c_in, c_out, k, stride,
                                                             pad):
    """Same blocks, same GEMM operands: identical numbers, and no graph recorded."""
    rng = np.random.default_rng(1)
    conv = Conv2d(c_in, c_out, k, stride=stride, padding=pad, rng=2, dtype=dtype)
    x = rng.normal(size=(3, c_in, 11, 17)).astype(dtype)
    ref = conv(ag.Tensor(x, requires_grad=True))
    assert ref.requires_grad
    for _ in range(2):                                    # the plan's buffers reused
        with ag.no_grad():
            got = conv(x)
        assert not got.requires_grad and got._parents == ()
        np.testing.assert_array_equal(got.data, ref.data)


@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-12), (np.float32, 1e-5)])
def test_conv_without_graph_contracts_channels_first_for_few_outputs(dtype, tol):
    """A 1-channel head (KH*KW*C_out <= C_in) contracts channels first under no_grad:
    the same products in another order, equal to round-off."""
    rng = np.random.default_rng(3)
    conv = Conv2d(16, 1, 3, padding=1, rng=4, dtype=dtype)
    x = rng.normal(size=(2, 16, 9, 13)).astype(dtype)
    ref = conv(ag.Tensor(x, requires_grad=True)).data
    with ag.no_grad():
        got = conv(x).data
    np.testing.assert_allclose(got, ref, rtol=tol, atol=tol)


def test_outputs_are_fresh_arrays_while_the_buffers_are_reused():
    """Two calls of one shape share the padded input and the scratch, never an output."""
    rng = np.random.default_rng(5)
    for c_out in (8, 1):                                  # im2col and contract-first
        conv = Conv2d(12, c_out, 3, padding=1, rng=6, dtype=np.float64)
        xs = [rng.normal(size=(2, 12, 5, 7)) for _ in range(2)]
        with ag.no_grad():
            first, second = conv(xs[0]).data, conv(xs[1]).data
        for x, got in zip(xs, (first, second)):
            want = conv(ag.Tensor(x, requires_grad=True)).data
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("change", ["adam", "in-place", "set_", "load_state_dict", "astype"])
def test_a_changed_weight_is_seen_by_the_next_prediction(change):
    """The weight matrix is cached per ``Tensor.version``: every way the project changes
    a weight bumps it (or replaces the array), and the next call reads the new weight."""
    rng = np.random.default_rng(7)
    conv = Conv2d(4, 6, 3, padding=1, rng=8)
    x = rng.normal(size=(2, 4, 6, 9)).astype(np.float32)
    with ag.no_grad():
        before = conv(x).data
    new = rng.normal(size=conv.weight.shape).astype(np.float32)
    if change == "adam":
        opt = Adam(conv.parameters(), lr=0.1)
        (conv(ag.Tensor(x)) ** 2).sum().backward()
        opt.step()
    elif change == "in-place":
        conv.weight.data -= 0.5
    elif change == "set_":
        conv.weight.set_(new)
    elif change == "load_state_dict":
        conv.load_state_dict({"weight": new, "bias": conv.bias.data.copy()})
    else:
        conv.astype(np.float64)
        x = x.astype(np.float64)
    with ag.no_grad():
        after = conv(x).data
    if change == "astype":                                # a new array, of another dtype
        assert after.dtype == np.float64
    else:
        assert not np.allclose(after, before)
    np.testing.assert_array_equal(after, conv(ag.Tensor(x, requires_grad=True)).data)


def test_nearest_upsampling_and_concat_keep_channels_last_memory():
    """The layout helpers change where values are stored, never the values."""
    rng = np.random.default_rng(9)
    y = np.ascontiguousarray(rng.normal(size=(2, 5, 6, 3))).transpose(0, 3, 1, 2)
    assert kernels.channels_last(y)
    up = kernels.repeat_nearest(y, 2, 2)
    assert kernels.channels_last(up)
    np.testing.assert_array_equal(up, np.repeat(np.repeat(y, 2, axis=2), 2, axis=3))
    other = np.ascontiguousarray(rng.normal(size=(2, 5, 6, 4))).transpose(0, 3, 1, 2)
    joined = kernels.concatenate([y, other], axis=1)
    assert kernels.channels_last(joined)
    np.testing.assert_array_equal(joined, np.concatenate([y, other], axis=1))
    with pytest.raises(ValueError):
        ag.concat([ag.Tensor(y), ag.Tensor(other[:1])], axis=1)


# -- the whole network -----------------------------------------------------------------
@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-11), (np.float32, 2e-5)])
@pytest.mark.parametrize("kw, hw", [
    ({}, (32, 104)),                                                    # the shipped shape
    ({"encoder": (8, 12, 16), "decoder": (6, 8, 10), "n_scales": 2}, (20, 36)),  # crops
    ({"encoder": (8, 12), "decoder": (4, 8), "n_scales": 1}, (15, 22)),
    ({"encoder": (8, 12, 16, 24), "decoder": (8, 8, 12, 16), "init_disp": None}, (13, 9))])
def test_dispnet_without_graph_equals_the_recorded_forward(dtype, tol, kw, hw):
    net = _random_net(dtype, **kw)
    rng = np.random.default_rng(9)
    rgb = rng.random((5,) + hw + (3,)).astype(dtype)
    ref = _autograd_disp(net, rgb)
    x = rgb.transpose(0, 3, 1, 2)                         # channels-last memory, as predict
    for _ in range(2):                                    # buffers reused on the 2nd call
        with ag.no_grad():
            got = net(x, scales=1)[0].data[:, 0]
        assert got.shape == ref.shape and got.dtype == dtype
        np.testing.assert_allclose(got, ref, rtol=tol, atol=0)
    with ag.no_grad():                                    # batch 1
        np.testing.assert_allclose(net(x[3:4], scales=1)[0].data[:, 0], ref[3:4], rtol=tol)


def test_the_estimator_is_the_forward_on_uint8_frames():
    net = _random_net(np.float32, encoder=(8, 12), decoder=(4, 8), n_scales=2)
    est = DepthEstimator(net, 2.0, {"height": 16, "width": 24})
    rgb = np.random.default_rng(10).integers(0, 256, (11, 16, 24, 3), dtype=np.uint8)
    ref = _autograd_disp(net, rgb.astype(np.float32) * (1 / 255.0))
    np.testing.assert_allclose(est.predict_disp(rgb), ref, rtol=2e-5, atol=0)


def test_a_training_step_is_seen_by_the_next_depth_prediction():
    net = _random_net(np.float32, encoder=(8, 12), decoder=(4, 8), n_scales=2)
    est = DepthEstimator(net, 2.0, {"height": 16, "width": 24})
    rgb = np.random.default_rng(11).integers(0, 256, (2, 16, 24, 3), dtype=np.uint8)
    before = est.predict(rgb)
    opt = Adam(net.parameters(), lr=0.05)
    net(rgb.transpose(0, 3, 1, 2).astype(np.float32) / 255)[0].sum().backward()
    opt.step()
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
def test_qnet_step_without_graph_equals_the_recorded_step(variant, channels):
    """Acting (``no_grad``) runs the schedule training runs: same Q and state, to the bit."""
    net = QNet(QNetConfig.for_variant(variant, in_channels=channels), rng=0)
    rng = np.random.default_rng(12)
    for batch in (1, 3, 16):
        obs = rng.random((batch, channels, 32, 104)).astype(np.float32)
        state = None
        if net.recurrent:
            state = tuple(ag.Tensor(rng.normal(size=(batch, 128)).astype(np.float32))
                          for _ in range(2))
        q_ref, state_ref = net.step(obs, state)           # gradients on
        assert q_ref.requires_grad
        with ag.no_grad():
            q, new_state = net.step(obs, state)
        assert not q.requires_grad
        np.testing.assert_array_equal(q.data, q_ref.data)
        if net.recurrent:
            for a, b in zip(new_state, state_ref):
                np.testing.assert_array_equal(a.data, b.data)
        else:
            assert new_state is None and state_ref is None


def test_an_optimizer_step_is_seen_by_the_next_action():
    from minid3rqn.rl.agent import Agent
    from minid3rqn.rl.replay import SequenceBatch
    agent = Agent(QNetConfig(), rng=0)
    rng = np.random.default_rng(13)
    obs = rng.random((4, 1, 32, 104)).astype(np.float32)
    before, _ = agent.q_values(obs)
    L, B = 3, 4
    batch = SequenceBatch(rng.random((L + 1, B, 1, 32, 104)).astype(np.float32),
                          rng.integers(5, size=(L, B)), np.ones((L, B), np.float32),
                          np.zeros((L, B), np.float32), np.ones((L, B), np.float32))
    agent.update(batch)
    after, _ = agent.q_values(obs)
    assert not np.allclose(after, before)
    with ag.no_grad():
        want = agent.online.step(obs)[0].data
    np.testing.assert_array_equal(after, want)
    np.testing.assert_array_equal(after, agent.online.step(obs)[0].data)   # graph on


@pytest.mark.skipif(not SHIPPED_Q.exists(), reason="no shipped Q-net")
def test_editing_qnet_head_changes_what_evaluate_flies(monkeypatch):
    """A student who edits ``QNet.head`` (here: Q -> -Q) changes the actions evaluation
    takes, not only what trains."""
    from minid3rqn.rl.evaluate import evaluate_policy
    from minid3rqn.rl.policies import QNetPolicy

    def flown():
        policy = QNetPolicy.load(SHIPPED_Q)
        act, seen = policy.act, []

        def recording(obs, started=None):
            actions = act(obs, started)
            seen.append(actions.copy())
            return actions
        policy.act = recording
        res = evaluate_policy(policy, "basic", n_flights=6, max_steps=8, progress=False)
        return np.concatenate(seen), res

    plain, plain_res = flown()
    head = QNet.head
    monkeypatch.setattr(QNet, "head", lambda self, z: -head(self, z))
    edited, edited_res = flown()
    assert len(plain) == len(edited) or plain_res.rate != edited_res.rate
    n = min(len(plain), len(edited))
    assert np.mean(plain[:n] != edited[:n]) > 0.5
