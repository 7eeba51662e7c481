"""Convolution and upsampling: gradients against central differences (float64), values
against naive loops, and clear errors."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from minid3rqn.autograd import Tensor, gradcheck
from minid3rqn.autograd import kernels
from minid3rqn.autograd.conv import conv2d, upsample
from minid3rqn.autograd.engine import no_grad, relu

pytestmark = pytest.mark.conv


def rand(*shape, seed=0):
    return np.random.default_rng([seed, *shape]).standard_normal(shape)


def naive_conv2d(x, w, b, stride, padding):
    """The definition, one output entry at a time."""
    (sh, sw), (ph, pw) = stride, padding
    xp = np.pad(x, ((0, 0), (0, 0), (ph, ph), (pw, pw)))
    N, _, Hp, Wp = xp.shape
    O, C, KH, KW = w.shape
    OH, OW = (Hp - KH) // sh + 1, (Wp - KW) // sw + 1
    y = np.zeros((N, O, OH, OW))
    for n in range(N):
        for o in range(O):
            for u in range(OH):
                for v in range(OW):
                    window = xp[n, :, u * sh:u * sh + KH, v * sw:v * sw + KW]
                    y[n, o, u, v] = np.sum(window * w[o]) + (0 if b is None else b[o])
    return y


# -- conv2d ------------------------------------------------------------------------------
# (N, C_in, C_out, H, W, KH, KW, stride, padding, bias)
CONV_CASES = [
    (2, 3, 4, 5, 6, 3, 3, 1, 0, True),
    (2, 2, 3, 6, 7, 3, 3, 1, 1, False),          # odd sizes, "same" padding
    (1, 2, 3, 7, 9, 3, 2, 2, 1, True),           # non-square kernel, stride 2
    (2, 1, 2, 8, 7, 4, 4, 2, 0, True),           # the QNet's 4x4 stride 2
    (1, 3, 2, 9, 10, 4, 2, 2, (1, 0), True),     # kernel a multiple of the stride, padded
    (1, 2, 2, 9, 8, 2, 3, 3, (1, 2), True),      # stride 3, padding pair
    (1, 3, 2, 5, 7, 1, 1, (2, 3), 0, True),      # 1x1 kernel, stride pair
    (1, 2, 2, 4, 5, 5, 3, 1, 2, False),          # kernel larger than the image
    (1, 2, 2, 7, 7, 3, 3, 4, 1, True),           # stride larger than the kernel
    (1, 5, 2, 5, 6, 3, 3, 1, 1, True),           # window rows of 15 values: pixel-major
    (2, 4, 3, 7, 6, 4, 3, 2, 1, False),          # 12 values: pixel-major, stride 2
]


@pytest.mark.parametrize("case", CONV_CASES)
def test_conv2d_gradcheck(case):
    N, C, O, H, W, KH, KW, stride, padding, bias = case
    arrays = [rand(N, C, H, W, seed=1), rand(O, C, KH, KW, seed=2)]
    if bias:
        arrays.append(rand(O, seed=3))
    gradcheck(lambda x, w, *b: conv2d(x, w, b[0] if b else None, stride, padding), arrays)


@pytest.mark.parametrize("case", CONV_CASES)
def test_conv2d_matches_naive_loop(case):
    N, C, O, H, W, KH, KW, stride, padding, bias = case
    x, w, b = rand(N, C, H, W, seed=4), rand(O, C, KH, KW, seed=5), rand(O, seed=6)
    b = b if bias else None
    pair = lambda v: v if isinstance(v, tuple) else (v, v)  # noqa: E731
    expected = naive_conv2d(x, w, b, pair(stride), pair(padding))
    got = conv2d(x, w, b, stride, padding)
    assert got.shape == expected.shape
    np.testing.assert_allclose(got.data, expected, rtol=1e-12, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 2), st.integers(1, 5), st.integers(1, 3), st.integers(1, 9),
       st.integers(1, 9), st.integers(1, 4), st.integers(1, 4), st.integers(1, 3),
       st.integers(1, 3), st.integers(0, 2), st.integers(0, 2))
def test_conv2d_and_its_adjoint_on_random_geometry(N, C, O, H, W, KH, KW, sh, sw, ph, pw):
    """Any geometry that fits: values match the naive loop, and the input gradient is
    conv2d's adjoint."""
    if KH > H + 2 * ph or KW > W + 2 * pw:
        with pytest.raises(ValueError, match="kernel"):
            conv2d(rand(N, C, H, W), rand(O, C, KH, KW), None, (sh, sw), (ph, pw))
        return
    x, w, b = rand(N, C, H, W, seed=1), rand(O, C, KH, KW, seed=2), rand(O, seed=3)
    xt = Tensor(x, requires_grad=True)
    yt = conv2d(xt, w, b, (sh, sw), (ph, pw))
    y = yt.data
    np.testing.assert_allclose(y, naive_conv2d(x, w, b, (sh, sw), (ph, pw)),
                               rtol=1e-12, atol=1e-12)
    v = rand(*y.shape, seed=4)
    yt.backward(v)
    np.testing.assert_allclose(np.sum((y - b[:, None, None]) * v), np.sum(x * xt.grad),
                               rtol=1e-10, atol=1e-10)


def test_conv2d_hand_computed():
    """A 1-channel 3x3 image, a 2x2 kernel: each output is a sum of a 2x2 window."""
    x = np.arange(9.0).reshape(1, 1, 3, 3)
    w = np.ones((1, 1, 2, 2))
    y = conv2d(x, w, np.array([0.5]))
    np.testing.assert_array_equal(y.data[0, 0], [[8.5, 12.5], [20.5, 24.5]])


def test_conv2d_without_input_gradient():
    """The first layer of a network: gradients for the weights and bias only."""
    gradcheck(lambda x, w, b: conv2d(x, w, b, 2, 1),
              [rand(2, 3, 6, 7), rand(4, 3, 3, 3, seed=1), rand(4, seed=2)],
              check_inputs=[1, 2])


@pytest.mark.parametrize("channels", [2, 6])         # tap-major and pixel-major cols
@pytest.mark.parametrize("block_bytes", [8, 2000, 9000])
def test_conv2d_blocks_give_the_same_result(monkeypatch, block_bytes, channels):
    """im2col runs in cache-sized blocks (rows of an image, or whole images); any
    block size must give the same values and gradients."""
    x, w, b = rand(3, channels, 9, 11), rand(3, channels, 3, 3, seed=1), rand(3, seed=2)
    g = rand(3, 3, 5, 6, seed=3)

    def run():
        xt, wt, bt = (Tensor(a, requires_grad=True) for a in (x, w, b))
        y = conv2d(xt, wt, bt, stride=2, padding=1)
        y.backward(g)
        return y.data, xt.grad, wt.grad, bt.grad

    reference = run()
    monkeypatch.setattr(kernels, "_BLOCK_BYTES", block_bytes)
    for expected, got in zip(reference, run()):
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
    gradcheck(lambda x, w: conv2d(x, w, None, 1, 1), [rand(2, 2, 4, 5), rand(2, 2, 3, 2)])


def test_conv2d_chain_with_relu():
    """Two convolutions in a row: the second reads the first's channels-last output."""
    def net(x, w1, w2):
        return conv2d(relu(conv2d(x, w1, None, 1, 1)), w2, None, 2, 0)
    gradcheck(net, [rand(2, 2, 6, 7), rand(3, 2, 3, 3, seed=1), rand(2, 3, 2, 2, seed=2)])


def test_conv2d_float32_in_float32_out():
    x = Tensor(rand(2, 3, 8, 9).astype(np.float32), requires_grad=True)
    w = Tensor(rand(4, 3, 3, 3, seed=1).astype(np.float32), requires_grad=True)
    b = Tensor(np.zeros(4, np.float32), requires_grad=True)
    y = conv2d(x, w, b, 1, 1)
    assert y.dtype == np.float32
    y.sum().backward()
    assert x.grad.dtype == w.grad.dtype == b.grad.dtype == np.float32
    expected = naive_conv2d(x.data.astype(np.float64), w.data.astype(np.float64), None,
                            (1, 1), (1, 1))
    np.testing.assert_allclose(y.data, expected, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("case", CONV_CASES)
def test_conv2d_input_gradient_is_its_adjoint(case):
    """<conv2d(x, w), y> = <x, J^T y>: the input gradient (the transposed convolution of
    y) is the adjoint of the convolution."""
    N, C, O, H, W, KH, KW, stride, padding, _ = case
    x, w = Tensor(rand(N, C, H, W, seed=7), requires_grad=True), rand(O, C, KH, KW, seed=8)
    cx = conv2d(x, w, None, stride, padding)
    y = rand(*cx.shape, seed=9)
    cx.backward(y)
    np.testing.assert_allclose(np.sum(cx.data * y), np.sum(x.data * x.grad), rtol=1e-10)


def test_conv2d_of_an_upsampled_image():
    """A 3x3 convolution of a nearest-x2-upsampled image (under no_grad: four 2x2
    convolutions of the small image) gives the plain convolution's values, and its
    gradients, with and without a graph."""
    x, w, b = rand(2, 3, 4, 5), rand(4, 3, 3, 3, seed=1), rand(4, seed=2)
    up = np.repeat(np.repeat(x, 2, axis=2), 2, axis=3)
    expected = naive_conv2d(up, w, b, (1, 1), (1, 1))
    xt, wt = Tensor(x, requires_grad=True), Tensor(w, requires_grad=True)
    got = conv2d(upsample(xt, 2), wt, b, 1, 1)
    np.testing.assert_allclose(got.data, expected, rtol=1e-12, atol=1e-12)
    g = rand(*got.shape, seed=3)
    got.backward(g)
    plain_w = Tensor(w, requires_grad=True)
    plain_x = Tensor(up, requires_grad=True)
    conv2d(plain_x, plain_w, b, 1, 1).backward(g)
    np.testing.assert_allclose(wt.grad, plain_w.grad, rtol=1e-10, atol=1e-12)
    small_grad = plain_x.grad.reshape(2, 3, 4, 2, 5, 2).sum(axis=(3, 5))
    np.testing.assert_allclose(xt.grad, small_grad, rtol=1e-10, atol=1e-12)
    with no_grad():
        np.testing.assert_allclose(conv2d(upsample(x, 2), w, b, 1, 1).data, expected,
                                   rtol=1e-12, atol=1e-12)
    gradcheck(lambda x, w: conv2d(upsample(x, 2), w, None, 1, 1),
              [rand(1, 2, 3, 4), rand(2, 2, 3, 3, seed=4)])


# -- upsample ----------------------------------------------------------------------------
@pytest.mark.parametrize("mode", ["nearest", "bilinear"])
@pytest.mark.parametrize("scale", [2, 3, (2, 3), 1])
def test_upsample_gradcheck(mode, scale):
    gradcheck(lambda x: upsample(x, scale, mode), [rand(2, 2, 3, 4)])


def test_upsample_nearest_repeats_pixels():
    x = rand(2, 3, 4, 5)
    y = upsample(x, 2, "nearest").data
    np.testing.assert_array_equal(y, x.repeat(2, axis=2).repeat(2, axis=3))


def test_upsample_bilinear_values():
    """align_corners=False: output pixel k reads the input at (k + 1/2)/s - 1/2,
    clamped to the image. Along one axis of [0, 4] at scale 2 that is
    t = -1/4, 1/4, 3/4, 5/4 -> 0, 1, 3, 4 (clamped at the left edge, then linear)."""
    row = np.array([0.0, 4.0]).reshape(1, 1, 1, 2)
    y = upsample(row, (1, 2), "bilinear").data
    np.testing.assert_allclose(y[0, 0, 0], [0.0, 1.0, 3.0, 4.0])
    ramp = np.add.outer(np.arange(5.0), 10 * np.arange(6.0))[None, None]  # linear
    y = upsample(ramp, 3, "bilinear").data[0, 0]
    t_row, t_col = (np.arange(15) + 0.5) / 3 - 0.5, (np.arange(18) + 0.5) / 3 - 0.5
    expected = np.add.outer(np.clip(t_row, 0, 4), 10 * np.clip(t_col, 0, 5))
    np.testing.assert_allclose(y, expected, atol=1e-12)


# -- bad inputs --------------------------------------------------------------------------
X, WEIGHT = rand(2, 3, 8, 8), rand(4, 3, 3, 3)


@pytest.mark.parametrize("call, error, match", [
    (lambda: conv2d(rand(3, 8, 8), WEIGHT), ValueError, "x must be a 4-D NCHW"),
    (lambda: conv2d(X, rand(4, 3, 3)), ValueError, "weight must be 4-D"),
    (lambda: conv2d(X, rand(4, 2, 3, 3)), ValueError, "x has 3 channels but weight"),
    (lambda: conv2d(X, WEIGHT, rand(3)), ValueError, "bias must have shape"),
    (lambda: conv2d(X, WEIGHT, stride=0), ValueError, "stride must be a positive"),
    (lambda: conv2d(X, WEIGHT, stride=-1), ValueError, "stride must be a positive"),
    (lambda: conv2d(X, WEIGHT, stride=(1, 2, 3)), ValueError, "stride"),
    (lambda: conv2d(X, WEIGHT, stride=1.5), ValueError, "stride"),
    (lambda: conv2d(X, WEIGHT, padding=-1), ValueError, "padding must be a non-negative"),
    (lambda: conv2d(rand(1, 3, 2, 2), WEIGHT), ValueError, "kernel 3x3 is larger"),
    (lambda: conv2d(X.astype(np.int64), WEIGHT), TypeError, "x must hold float"),
    (lambda: conv2d(X, WEIGHT.astype(np.int32)), TypeError, "weight must hold float"),
    (lambda: conv2d(X, WEIGHT.astype(np.float32)), TypeError, "mix dtypes"),
    (lambda: conv2d(X, WEIGHT, rand(4).astype(np.float32)), TypeError, "bias is float32"),
    (lambda: upsample(X, 2, "bicubic"), ValueError, "mode must be"),
    (lambda: upsample(X, 0), ValueError, "scale_factor must be a positive"),
    (lambda: upsample(X, 1.5), ValueError, "scale_factor"),
    (lambda: upsample(rand(8, 8), 2), ValueError, "x must be a 4-D NCHW"),
])
def test_bad_inputs_raise_clear_errors(call, error, match):
    with pytest.raises(error, match=match):
        call()
