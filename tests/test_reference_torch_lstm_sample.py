"""LSTM and bilinear sampling against PyTorch (skipped when torch is not installed)."""
import numpy as np
import pytest

from minid3rqn.autograd.engine import Tensor
from minid3rqn.autograd.lstm import lstm
from minid3rqn.autograd.sample import bilinear_sample

torch = pytest.importorskip("torch")

pytestmark = [pytest.mark.torch]

TOL = dict(rtol=1e-10, atol=1e-12)


def _torch_lstm(steps, batch, in_size, hidden, seed):
    torch.manual_seed(seed)
    net = torch.nn.LSTM(in_size, hidden).double()
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((steps, batch, in_size))
    h0 = rng.standard_normal((batch, hidden))
    c0 = rng.standard_normal((batch, hidden))
    return net, x, h0, c0


def _ours_from(net, x, h0, c0):
    """Leaf tensors with torch's values; bias = b_ih + b_hh."""
    weights = [net.weight_ih_l0, net.weight_hh_l0]
    arrays = [x, h0, c0] + [w.detach().numpy().copy() for w in weights]
    arrays.append((net.bias_ih_l0 + net.bias_hh_l0).detach().numpy().copy())
    return [Tensor(a, requires_grad=True) for a in arrays]


def _torch_grads(net, x, h0, c0, covectors, steps_to_use):
    xt = torch.tensor(x[:steps_to_use], requires_grad=True)
    h0t = torch.tensor(h0[None], requires_grad=True)
    c0t = torch.tensor(c0[None], requires_grad=True)
    out, (h, c) = net(xt, (h0t, c0t))
    u_out, u_h, u_c = (torch.tensor(u) for u in covectors)
    ((out * u_out).sum() + (h[0] * u_h).sum() + (c[0] * u_c).sum()).backward()
    grads = [xt.grad, h0t.grad[0], c0t.grad[0], net.weight_ih_l0.grad, net.weight_hh_l0.grad]
    np.testing.assert_allclose(net.bias_ih_l0.grad, net.bias_hh_l0.grad, **TOL)
    grads.append(net.bias_ih_l0.grad)
    return [out.detach().numpy(), h[0].detach().numpy(), c[0].detach().numpy()], \
        [g.numpy() for g in grads]


def test_lstm_matches_torch_values_and_gradients():
    steps, batch, in_size, hidden = 4, 3, 5, 6
    net, x, h0, c0 = _torch_lstm(steps, batch, in_size, hidden, seed=0)
    rng = np.random.default_rng(1)
    covectors = [rng.standard_normal((steps, batch, hidden)),
                 rng.standard_normal((batch, hidden)), rng.standard_normal((batch, hidden))]
    ref_values, ref_grads = _torch_grads(net, x, h0, c0, covectors, steps)

    tensors = _ours_from(net, x, h0, c0)
    outputs, (h, c) = lstm(*tensors)
    for ours, ref in zip([outputs.data, h.data, c.data], ref_values):
        np.testing.assert_allclose(ours, ref, **TOL)
    ((outputs * covectors[0]).sum() + (h * covectors[1]).sum()
     + (c * covectors[2]).sum()).backward()
    for t, ref in zip(tensors, ref_grads):
        np.testing.assert_allclose(t.grad, ref, **TOL)


@pytest.mark.parametrize("mode", ["zeros", "border"])
def test_bilinear_sample_matches_grid_sample(mode):
    rng = np.random.default_rng(4)
    n, ch, height, width, ho, wo = 2, 3, 6, 8, 5, 7
    image = rng.standard_normal((n, ch, height, width))
    coords = np.stack([rng.uniform(-2.5, width + 1.5, (n, ho, wo)),
                       rng.uniform(-2.5, height + 1.5, (n, ho, wo))], axis=-1)
    g = rng.standard_normal((n, ch, ho, wo))

    image_t = torch.tensor(image, requires_grad=True)
    coords_t = torch.tensor(coords, requires_grad=True)
    scale = torch.tensor([2.0 / (width - 1), 2.0 / (height - 1)], dtype=torch.float64)
    grid = coords_t * scale - 1                      # pixel -> [-1, 1], align_corners=True
    ref = torch.nn.functional.grid_sample(image_t, grid, mode="bilinear", padding_mode=mode,
                                          align_corners=True)
    (ref * torch.tensor(g)).sum().backward()

    image_o, coords_o = Tensor(image, requires_grad=True), Tensor(coords, requires_grad=True)
    out, _ = bilinear_sample(image_o, coords_o, mode)
    out.backward(g)
    np.testing.assert_allclose(out.data, ref.detach().numpy(), **TOL)
    np.testing.assert_allclose(image_o.grad, image_t.grad.numpy(), **TOL)
    np.testing.assert_allclose(coords_o.grad, coords_t.grad.numpy(), rtol=1e-9, atol=1e-10)
