"""Bilinear sampling (the view-synthesis warp): gradients, values, the mask, errors."""
import math

import numpy as np
import pytest

from minid3rqn.autograd.engine import Tensor
from minid3rqn.autograd.gradcheck import gradcheck
from minid3rqn.autograd.sample import bilinear_sample

pytestmark = pytest.mark.sample

MODES = ["zeros", "border"]


def pixel_grid(height, width, dtype):
    """The identity sampling grid: (H, W, 2) with ``grid[v, u] = (u, v)`` = (x, y)."""
    ys, xs = np.meshgrid(np.arange(height, dtype=dtype), np.arange(width, dtype=dtype),
                         indexing="ij")
    return np.stack([xs, ys], axis=-1)


def _jitter(coords, gap=0.05):
    """Move coordinates off integer grid lines (and off the clamp edges 0 and W-1, H-1),
    where bilinear sampling is not differentiable."""
    coords = coords.copy()
    frac = coords - np.floor(coords)
    near = (frac < gap) | (frac > 1 - gap)
    coords[near] += 2 * gap
    return coords


def _border_coords(rng, n, ho, wo, height, width):
    """Coordinates spread over the image, near its edges and outside (up to 2 px)."""
    x = rng.uniform(-2.5, width + 1.5, (n, ho, wo))
    y = rng.uniform(-2.5, height + 1.5, (n, ho, wo))
    coords = np.stack([x, y], axis=-1)
    # a few hand-picked points hugging each edge, inside and outside
    edge = np.array([[-0.3, 1.4], [width - 1 + 0.3, 2.2], [1.7, -0.6], [2.3, height - 1 + 0.7],
                     [-1.2, -1.3], [width - 0.6, height - 0.8], [0.2, 0.3], [width + 0.5, 1.5]])
    flat = coords.reshape(-1, 2)
    k = min(len(edge), len(flat))
    flat[:k] = edge[:k]
    return _jitter(coords)


def _naive(image, coords, padding_mode):
    """Per-pixel loops, straight from the formula."""
    n, ch, height, width = image.shape
    _, ho, wo, _ = coords.shape
    out = np.zeros((n, ch, ho, wo))
    for b in range(n):
        for v in range(ho):
            for u in range(wo):
                x, y = coords[b, v, u]
                if padding_mode == "border":
                    x, y = min(max(x, 0), width - 1), min(max(y, 0), height - 1)
                x0, y0 = math.floor(x), math.floor(y)
                wx, wy = x - x0, y - y0
                for dy, ky in ((0, 1 - wy), (1, wy)):
                    for dx, kx in ((0, 1 - wx), (1, wx)):
                        yy, xx = y0 + dy, x0 + dx
                        if 0 <= yy < height and 0 <= xx < width:
                            out[b, :, v, u] += ky * kx * image[b, :, yy, xx]
    return out


# -- gradients -------------------------------------------------------------------------
@pytest.mark.parametrize("mode", MODES)
def test_gradcheck_image_and_coords_elementwise(mode):
    rng = np.random.default_rng(0)
    image = rng.standard_normal((2, 2, 4, 5))
    coords = _border_coords(rng, 2, 3, 4, height=4, width=5)
    assert gradcheck(lambda i, c: bilinear_sample(i, c, mode)[0], [image, coords])


@pytest.mark.parametrize("mode", MODES)
def test_gradcheck_larger_directional(mode):
    rng = np.random.default_rng(1)
    image = rng.standard_normal((3, 3, 7, 9))
    coords = _border_coords(rng, 3, 6, 8, height=7, width=9)
    assert gradcheck(lambda i, c: bilinear_sample(i, c, mode)[0], [image, coords],
                     elementwise=False, n_directions=4)


@pytest.mark.parametrize("mode", MODES)
def test_gradcheck_each_input_alone(mode):
    rng = np.random.default_rng(2)
    image = rng.standard_normal((1, 2, 3, 4))
    coords = _border_coords(rng, 1, 2, 3, height=3, width=4)
    fn = lambda i, c: bilinear_sample(i, c, mode)[0]
    assert gradcheck(fn, [image, coords], check_inputs=[0])
    assert gradcheck(fn, [image, coords], check_inputs=[1])


def test_coords_gradient_zero_where_clamped_or_far_outside():
    rng = np.random.default_rng(3)
    image = Tensor(rng.standard_normal((1, 2, 4, 5)))
    coords = np.array([[[[-3.3, 1.5], [2.5, 7.2], [6.4, -4.1], [1.5, 2.5]]]])
    for mode in MODES:
        c = Tensor(coords.copy(), requires_grad=True)
        out, _ = bilinear_sample(image, c, mode)
        out.backward(np.ones(out.shape))
        g = c.grad[0, 0]
        if mode == "border":   # x clamped in 0 and 2; y clamped in 1 and 2
            assert g[0, 0] == 0 and g[1, 1] == 0 and g[2, 0] == 0 and g[2, 1] == 0
            assert g[0, 1] != 0 and g[1, 0] != 0
        else:                  # more than a pixel outside: every corner reads zero
            assert np.all(g[:3] == 0)
        assert np.all(g[3] != 0)


# -- values -------------------------------------------------------------------------------
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_identity_grid_reproduces_image(mode, dtype):
    image = np.random.default_rng(4).standard_normal((2, 3, 5, 7)).astype(dtype)
    grid = np.broadcast_to(pixel_grid(5, 7, dtype), (2, 5, 7, 2))
    out, valid = bilinear_sample(image, grid, mode)
    assert out.dtype == dtype and valid.dtype == dtype
    np.testing.assert_array_equal(out.data, image)
    assert np.all(valid == 1)


@pytest.mark.parametrize("mode", MODES)
def test_float32_gradients_stay_float32(mode):
    rng = np.random.default_rng(7)
    image = Tensor(rng.standard_normal((2, 3, 4, 5)).astype(np.float32), requires_grad=True)
    coords = Tensor(_border_coords(rng, 2, 3, 3, 4, 5).astype(np.float32), requires_grad=True)
    out, valid = bilinear_sample(image, coords, mode)
    out.backward(np.ones(out.shape, np.float32))
    assert out.dtype == valid.dtype == image.grad.dtype == coords.grad.dtype == np.float32
    assert image.grad.shape == image.shape and coords.grad.shape == coords.shape


@pytest.mark.parametrize("mode", MODES)
def test_integer_shift_reproduces_shifted_image(mode):
    image = np.random.default_rng(5).standard_normal((1, 2, 4, 6))
    grid = pixel_grid(4, 6, np.float64)[None] + np.array([1.0, -2.0])   # x + 1, y - 2
    out, valid = bilinear_sample(image, grid, mode)
    out = out.data
    # out[v, u] = image[v - 2, u + 1] where that exists
    np.testing.assert_allclose(out[..., 2:, :5], image[..., :2, 1:], atol=1e-15)
    expected_valid = np.zeros((4, 6))
    expected_valid[2:, :5] = 1
    np.testing.assert_array_equal(valid[0, 0], expected_valid)
    if mode == "zeros":
        assert np.all(out[..., :2, :] == 0) and np.all(out[..., :, 5] == 0)
    else:
        np.testing.assert_allclose(out[..., 2:, 5], image[..., :2, 5], atol=1e-15)
        np.testing.assert_allclose(out[..., 0, :5], image[..., 0, 1:], atol=1e-15)


@pytest.mark.parametrize("mode", MODES)
def test_values_match_naive_loop(mode):
    rng = np.random.default_rng(6)
    image = rng.standard_normal((2, 3, 5, 6))
    coords = np.stack([rng.uniform(-2.5, 7.5, (2, 4, 5)), rng.uniform(-2.5, 6.5, (2, 4, 5))], -1)
    coords[0, 0, :3] = [[0, 0], [5, 4], [-1, 2]]           # exact corners and edges too
    out, _ = bilinear_sample(image, coords, mode)
    np.testing.assert_allclose(out.data, _naive(image, coords, mode), rtol=1e-12, atol=1e-12)


def test_zeros_mode_fades_within_one_pixel_outside():
    image = np.ones((1, 1, 3, 3))
    coords = np.array([[[[-0.25, 1.0], [2.5, 1.0], [1.0, -1.0], [-1.0, -1.0], [3.1, 1.0]]]])
    out, _ = bilinear_sample(image, coords, "zeros")
    np.testing.assert_allclose(out.data[0, 0, 0], [0.75, 0.5, 0.0, 0.0, 0.0])
    out, _ = bilinear_sample(image, coords, "border")
    np.testing.assert_allclose(out.data[0, 0, 0], 1.0)


def test_valid_mask():
    coords = np.array([[[[0.0, 0.0], [3.0, 2.0], [-1e-9, 1.0], [3.0 + 1e-9, 1.0],
                         [1.5, 2.0001], [1.5, 1.5], [np.inf, 0.0], [1.0, -5.0]]]])
    _, valid = bilinear_sample(np.zeros((1, 2, 3, 4)), coords)
    assert isinstance(valid, np.ndarray) and valid.shape == (1, 1, 1, 8)
    np.testing.assert_array_equal(valid[0, 0, 0], [1, 1, 0, 0, 0, 1, 0, 0])


def test_far_out_and_infinite_coordinates_are_safe():
    image = np.ones((1, 1, 3, 3))
    coords = np.array([[[[1e30, 1.0], [-np.inf, 1.0], [1.0, np.inf]]]])
    out, valid = bilinear_sample(image, coords, "zeros")
    np.testing.assert_array_equal(out.data, 0)
    out, _ = bilinear_sample(image, coords, "border")
    np.testing.assert_array_equal(out.data, 1)


# -- bad inputs --------------------------------------------------------------------------
def test_bad_inputs_raise_clear_errors():
    image = np.zeros((2, 3, 4, 5))
    coords = np.zeros((2, 6, 7, 2))
    cases = [
        ((image, coords[..., :1]), ValueError, "coords must be 4-D .* got shape"),
        ((image, np.zeros((2, 6, 7, 3))), ValueError, "coords must be"),
        ((image, coords[0]), ValueError, "coords must be 4-D"),
        ((image, coords[:1]), ValueError, "same batch size"),
        ((image[0], coords), ValueError, "image must be 4-D"),
        ((image.astype(np.int64), coords), TypeError, "image must hold float"),
        ((image, coords.astype(np.int32)), TypeError, "coords must hold float"),
        ((image.astype(np.float32), coords), TypeError, "mix dtypes"),
    ]
    for args, error, message in cases:
        with pytest.raises(error, match=message):
            bilinear_sample(*args)
    with pytest.raises(ValueError, match="NaN"):
        bilinear_sample(image, np.full((2, 6, 7, 2), np.nan))
    with pytest.raises(ValueError, match="padding_mode"):
        bilinear_sample(image, coords, "reflection")
