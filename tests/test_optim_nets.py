"""Losses, optimizers, Module and layers: gradients, convergence, saving, loading."""
import numpy as np
import pytest

from minid3rqn.autograd import Tensor, gradcheck
from minid3rqn.autograd.optim import Adam, clip_grad_norm
from minid3rqn.autograd.losses import huber_loss, mse_loss
from minid3rqn.nets import Linear, Module, Sequential, Tanh


@pytest.mark.optim
@pytest.mark.parametrize("loss", [mse_loss,
                                  lambda p, t: huber_loss(p, t, delta=0.7)])
def test_losses_gradcheck(loss):
    rng = np.random.default_rng(0)
    target = rng.standard_normal((4, 3))
    pred = target + rng.choice([-1, 1], (4, 3)) * rng.uniform(0.1, 2.0, (4, 3))
    gradcheck(lambda p: loss(p, target), [pred])


@pytest.mark.optim
def test_huber_is_quadratic_then_linear():
    r = np.array([0.5, 3.0])
    loss = huber_loss(Tensor(r), Tensor(np.zeros(2)), delta=1.0, reduction="none")
    np.testing.assert_allclose(loss.data, [0.125, 2.5])


@pytest.mark.optim
def test_loss_shape_mismatch_is_reported():
    with pytest.raises(ValueError, match=r"prediction has shape \(3,\) but target"):
        mse_loss(Tensor(np.ones(3)), np.ones(4))


def _toy_regression(seed=0):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-2, 2, size=(256, 1)).astype(np.float32)
    y = (np.sin(2 * x) + 0.5 * x).astype(np.float32)
    return x, y


@pytest.mark.optim
@pytest.mark.nets
def test_tiny_mlp_fits_a_curve():
    x, y = _toy_regression()
    net = Sequential(Linear(1, 32, rng=1), Tanh(), Linear(32, 32, rng=2), Tanh(),
                     Linear(32, 1, rng=3))
    opt = Adam(net.parameters(), lr=1e-2)
    first = None
    for step in range(400):
        loss = mse_loss(net(Tensor(x)), y)
        first = first if first is not None else loss.item()
        opt.zero_grad()
        loss.backward()
        clip_grad_norm(net.parameters(), 10.0)
        opt.step()
    assert loss.item() < 0.05 * first


@pytest.mark.optim
def test_clip_grad_norm_scales_to_the_bound_and_refuses_nan():
    p = Tensor(np.zeros(4), requires_grad=True)
    p.grad = np.array([3.0, 4.0, 0.0, 0.0])
    assert clip_grad_norm([p], 1.0) == pytest.approx(5.0)
    np.testing.assert_allclose(np.linalg.norm(p.grad), 1.0, rtol=1e-6)
    p.grad = np.array([np.nan, 0, 0, 0])
    with pytest.raises(FloatingPointError, match="NaN"):
        clip_grad_norm([p], 1.0)


@pytest.mark.optim
def test_adam_state_roundtrip_resumes_exactly():
    def run(n, resume_from=None):
        net = Linear(3, 2, rng=0)
        opt = Adam(net.parameters(), lr=0.1)
        if resume_from is not None:
            net.load_state_dict(resume_from[0])
            opt.load_state_dict(resume_from[1])
        x = np.ones((5, 3), np.float32)
        for _ in range(n):
            opt.zero_grad()
            mse_loss(net(Tensor(x)), np.zeros((5, 2), np.float32)).backward()
            opt.step()
        return net.state_dict(), {k: v.copy() for k, v in opt.state_dict().items()}

    straight = run(6)
    half = run(3)
    resumed = run(3, resume_from=half)
    for k in straight[0]:
        np.testing.assert_array_equal(straight[0][k], resumed[0][k])


class _Net(Module):
    def __init__(self):
        self.body = Sequential(Linear(4, 8, rng=0), Tanh())
        self.heads = [Linear(8, 2, rng=1), Linear(8, 1, rng=2)]

    def forward(self, x):
        h = self.body(x)
        return self.heads[0](h) + self.heads[1](h)


@pytest.mark.nets
def test_module_discovers_parameters_by_dotted_name():
    names = [n for n, _ in _Net().named_parameters()]
    assert names == ["body.layers.0.weight", "body.layers.0.bias", "heads.0.weight",
                     "heads.0.bias", "heads.1.weight", "heads.1.bias"]


@pytest.mark.nets
def test_save_load_roundtrip_and_clear_errors(tmp_path):
    a, b = _Net(), _Net()
    for p in b.parameters():
        p.data[...] = 0
    path = a.save(tmp_path / "net.npz", metadata={"seed": 0})
    assert b.load(path) == {"seed": 0}
    for (n, pa), (_, pb) in zip(a.named_parameters(), b.named_parameters()):
        np.testing.assert_array_equal(pa.data, pb.data)
    state = a.state_dict()
    state["heads.0.weight"] = np.zeros((3, 8))
    with pytest.raises(ValueError, match=r"heads.0.weight expects shape \(2, 8\)"):
        b.load_state_dict(state)
    del state["heads.0.weight"]
    with pytest.raises(KeyError, match="missing.*heads.0.weight"):
        b.load_state_dict(state)
    assert not list(tmp_path.glob("*.tmp"))  # the atomic write left no temporary file


@pytest.mark.nets
def test_same_seed_same_network():
    a, b = Linear(5, 3, rng=7), Linear(5, 3, rng=7)
    np.testing.assert_array_equal(a.weight.data, b.weight.data)
    assert not np.array_equal(a.weight.data, Linear(5, 3, rng=8).weight.data)


def test_blas_core_names_the_kernels_openblas_runs():
    """io.blas_core reports OpenBLAS's kernel choice, which OPENBLAS_CORETYPE can set: the
    reason a long run's numbers can differ between CPUs (docs/d3rqn.md, section 7)."""
    import os
    import platform
    import subprocess
    import sys
    from minid3rqn.io import blas_core, machine
    core = blas_core()
    assert isinstance(core, str) and core
    assert machine()["blas_core"] == core and machine()["numpy"] == np.__version__
    if core == "unknown" or platform.machine() not in ("x86_64", "AMD64"):
        pytest.skip(f"no OpenBLAS kernel choice to check here ({core}, {platform.machine()})")
    env = dict(os.environ, OPENBLAS_CORETYPE="Sandybridge")     # any x86-64 CPU with AVX
    got = subprocess.run([sys.executable, "-c", "from minid3rqn.io import blas_core; "
                          "print(blas_core())"], env=env, capture_output=True, text=True,
                         check=True).stdout.strip()
    assert got == "Sandybridge"


@pytest.mark.nets
def test_linear_gradcheck_through_the_layer():
    layer = Linear(3, 2, rng=0).astype(np.float64)
    w, b = layer.weight, layer.bias

    def f(x, wd, bd):
        layer.weight, layer.bias = wd, bd
        return layer(x)
    gradcheck(f, [np.random.default_rng(1).standard_normal((4, 3)), w.data.copy(),
                  b.data.copy()])
