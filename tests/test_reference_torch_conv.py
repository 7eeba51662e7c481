"""conv2d and upsample against PyTorch, values and gradients (float64; skipped when torch
is not installed)."""
import numpy as np
import pytest

from minid3rqn.autograd import Tensor
from minid3rqn.autograd.conv import conv2d, upsample

torch = pytest.importorskip("torch")
F = torch.nn.functional

pytestmark = [pytest.mark.torch, pytest.mark.conv]


def rand(*shape, seed=0):
    return np.random.default_rng([seed, *shape]).standard_normal(shape)


def compare(ours, theirs, arrays, rtol=1e-10, atol=1e-12):
    """Same values, and same gradients for one random covector on the output."""
    ts = [Tensor(a, requires_grad=True) for a in arrays]
    y = ours(*ts)
    tt = [torch.tensor(a, requires_grad=True) for a in arrays]
    yt = theirs(*tt)
    assert y.shape == tuple(yt.shape)
    np.testing.assert_allclose(y.data, yt.detach().numpy(), rtol=rtol, atol=atol)
    g = rand(*y.shape, seed=99).astype(arrays[0].dtype)
    y.backward(g)
    yt.backward(torch.tensor(g))
    for i, (ours_t, theirs_t) in enumerate(zip(ts, tt)):
        np.testing.assert_allclose(ours_t.grad, theirs_t.grad.numpy(), rtol=rtol, atol=atol,
                                   err_msg=f"gradient of input {i}")


@pytest.mark.parametrize("N, C, O, H, W, KH, KW, stride, padding, bias", [
    (2, 3, 4, 7, 9, 3, 3, 1, 1, True),
    (2, 3, 5, 11, 13, 7, 7, 2, 3, True),
    (3, 2, 4, 10, 12, 5, 3, (2, 3), (2, 1), False),
    (4, 1, 4, 32, 104, 4, 4, 2, 0, True),          # the QNet's first layer
    (1, 4, 2, 9, 9, 3, 3, 3, 0, True),
    (2, 16, 16, 20, 30, 3, 3, 1, 1, True),         # several cache blocks
])
def test_conv2d_matches_torch(N, C, O, H, W, KH, KW, stride, padding, bias):
    arrays = [rand(N, C, H, W, seed=1), rand(O, C, KH, KW, seed=2)]
    if bias:
        arrays.append(rand(O, seed=3))
    compare(lambda x, w, *b: conv2d(x, w, b[0] if b else None, stride, padding),
            lambda x, w, *b: F.conv2d(x, w, b[0] if b else None, stride, padding), arrays)


@pytest.mark.parametrize("mode", ["nearest", "bilinear"])
@pytest.mark.parametrize("scale", [2, 3, 4])
@pytest.mark.parametrize("shape", [(2, 3, 4, 5), (1, 2, 1, 7), (4, 1, 8, 26)])
def test_upsample_matches_torch(mode, scale, shape):
    extra = {"align_corners": False} if mode == "bilinear" else {}
    compare(lambda x: upsample(x, scale, mode),
            lambda x: F.interpolate(x, scale_factor=scale, mode=mode, **extra), [rand(*shape)])


def test_float32_at_a_project_shape():
    """A DispNet-sized layer in float32 (the training dtype): many cache blocks."""
    arrays = [rand(4, 16, 32, 104, seed=1).astype(np.float32),
              (0.1 * rand(32, 16, 3, 3, seed=2)).astype(np.float32),
              rand(32, seed=3).astype(np.float32)]
    compare(lambda x, w, b: conv2d(x, w, b, 1, 1), lambda x, w, b: F.conv2d(x, w, b, 1, 1),
            arrays, rtol=1e-4, atol=1e-3)
