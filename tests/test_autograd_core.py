"""The engine and its basic ops: every gradient against central differences (float64)."""
import numpy as np
import pytest

from minid3rqn import autograd as ag
from minid3rqn.autograd import GradcheckError, Tensor, gradcheck

pytestmark = pytest.mark.autograd


def rand(*shape, seed=0, low=None):
    x = np.random.default_rng([seed, len(shape), *shape]).standard_normal(shape)
    return np.abs(x) + low if low is not None else x


# -- elementwise, with broadcasting ----------------------------------------------------
BINARY = {
    "add": ag.add, "sub": ag.sub, "mul": ag.mul,
    "div": lambda a, b: ag.div(a, ag.abs(b) + 0.5),
    "maximum": ag.maximum, "minimum": ag.minimum,
}


@pytest.mark.parametrize("name", sorted(BINARY))
@pytest.mark.parametrize("shapes", [((3, 4), (3, 4)), ((2, 3, 4), (4,)), ((3, 1), (1, 5)),
                                    ((2, 1, 3), (4, 1)), ((), (2, 3))])
def test_binary_ops_with_broadcasting(name, shapes):
    a, b = rand(*shapes[0], seed=1), rand(*shapes[1], seed=2)
    gradcheck(BINARY[name], [a, b])


UNARY = {
    "neg": ag.neg, "exp": ag.exp, "tanh": ag.tanh, "sigmoid": ag.sigmoid,
    "relu": ag.relu, "elu": ag.elu, "abs": ag.abs,
    "log": lambda x: ag.log(ag.abs(x) + 0.1), "sqrt": lambda x: ag.sqrt(ag.abs(x) + 0.1),
    "pow3": lambda x: x ** 3, "pow_half": lambda x: (ag.abs(x) + 0.2) ** 0.5,
    "clip": lambda x: ag.clip(x, -0.5, 0.7),
    "where": lambda x: ag.where(x.data > 0, x * 2, x ** 2),
}


@pytest.mark.parametrize("name", sorted(UNARY))
def test_unary_ops(name):
    x = rand(3, 5, seed=3)
    x[np.abs(x) < 0.05] += 0.2  # keep away from kinks (relu, abs) where eps would straddle
    gradcheck(UNARY[name], [x])


def test_sigmoid_does_not_overflow():
    x = Tensor(np.array([-1000.0, 0.0, 1000.0]))
    assert np.all(np.isfinite(ag.sigmoid(x).data))
    np.testing.assert_allclose(ag.sigmoid(x).data, [0.0, 0.5, 1.0])


@pytest.mark.parametrize("shapes", [((3, 4), (4, 2)), ((2, 3, 4), (4, 5)), ((4,), (4, 3)),
                                    ((3, 4), (4,)), ((4,), (4,)), ((2, 1, 3, 4), (5, 4, 2))])
def test_matmul(shapes):
    gradcheck(ag.matmul, [rand(*shapes[0], seed=4), rand(*shapes[1], seed=5)])


# -- reductions ------------------------------------------------------------------------
@pytest.mark.parametrize("op", [ag.sum, ag.mean])
@pytest.mark.parametrize("axis", [None, 0, 1, -1, (0, 2)])
@pytest.mark.parametrize("keepdims", [False, True])
def test_reductions(op, axis, keepdims):
    gradcheck(lambda x: op(x, axis=axis, keepdims=keepdims), [rand(2, 3, 4, seed=6)])


@pytest.mark.parametrize("axis", [0, 1, -1])
def test_log_softmax_gradcheck(axis):
    gradcheck(lambda x: ag.log_softmax(x, axis=axis), [rand(2, 3, 4, seed=7)])


def test_log_softmax_values_and_no_overflow():
    x = np.array([[1.0, 2.0, 3.0], [1000.0, 0.0, -1000.0]])
    y = ag.log_softmax(Tensor(x)).data
    ref = np.log(np.exp([1.0, 2.0, 3.0]) / np.exp([1.0, 2.0, 3.0]).sum())
    np.testing.assert_allclose(y[0], ref)
    assert np.all(np.isfinite(y)) and y[1, 0] == 0.0
    np.testing.assert_allclose(np.exp(y).sum(axis=-1), 1.0)
    # adding a constant along the axis changes nothing (only differences matter)
    np.testing.assert_allclose(ag.log_softmax(Tensor(x[:1] + 5.0)).data, y[:1])
    assert ag.log_softmax(Tensor(x.astype(np.float32))).dtype == np.float32


# -- shape ops -------------------------------------------------------------------------
def test_reshape_transpose_flatten():
    gradcheck(lambda x: ag.reshape(x, (4, 6)) * np.arange(24.0).reshape(4, 6), [rand(2, 3, 4)])
    gradcheck(lambda x: ag.transpose(x, (2, 0, 1)) * rand(4, 2, 3, seed=9), [rand(2, 3, 4)])
    gradcheck(lambda x: ag.flatten(x) * rand(2, 12, seed=9), [rand(2, 3, 4)])


@pytest.mark.parametrize("index", [
    (slice(1, 3),), (slice(None), 2), (Ellipsis, slice(0, None, 2)), (1, slice(None), -1),
    (np.array([0, 2, 2, 1]), np.array([1, 0, 0, 3])),  # a gather with a repeat: Q(s, a)
    (np.array([True, False, True]),),
])
def test_getitem(index):
    gradcheck(lambda x: x[index] * 1.5, [rand(3, 4, 2)])


def test_concat_stack_pad():
    a, b = rand(2, 3, seed=1), rand(2, 5, seed=2)
    gradcheck(lambda a, b: ag.concat([a, b], axis=1) * rand(2, 8, seed=3), [a, b])
    gradcheck(lambda a, b: ag.stack([a, b * 2], axis=1) * rand(2, 2, 3, seed=3), [a, a + 1])
    gradcheck(lambda x: ag.pad(x, ((1, 2), (0, 3))) * rand(5, 6, seed=4), [rand(2, 3)])
    gradcheck(lambda x: ag.pad(x, ((2, 1), (1, 2)), mode="edge") * rand(5, 6, seed=4),
              [rand(2, 3)])


# -- the engine ------------------------------------------------------------------------
def test_gradients_accumulate_and_zero_grad_clears():
    x = Tensor(np.array([2.0, -1.0]), requires_grad=True)
    (x * x).sum().backward()
    (x * 3).sum().backward()
    np.testing.assert_allclose(x.grad, 2 * x.data + 3)
    x.zero_grad()
    assert x.grad is None


def test_shared_subexpression_receives_all_paths():
    x = Tensor(np.array(1.5), requires_grad=True)
    y = x * x
    (y * y + y).backward()  # x^4 + x^2 -> 4x^3 + 2x
    np.testing.assert_allclose(x.grad, 4 * 1.5 ** 3 + 2 * 1.5)


def test_deep_graph_does_not_recurse():
    x = Tensor(np.ones(3), requires_grad=True)
    y = x
    for _ in range(20000):  # far deeper than Python's recursion limit
        y = y * 1.0 + 0.0
    y.sum().backward()
    np.testing.assert_allclose(x.grad, np.ones(3))


def test_no_grad_records_nothing():
    w = Tensor(np.ones(2), requires_grad=True)
    with ag.no_grad():
        y = w * 2
    assert not y.requires_grad and y._parents == ()
    assert ag.is_grad_enabled()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_dtypes_are_preserved(dtype):
    x = Tensor(np.ones((2, 3), dtype=dtype), requires_grad=True)
    y = ag.mean(ag.tanh(x * 2.5 + 1) @ np.ones((3, 2), dtype=dtype)) ** 2
    assert y.dtype == dtype
    y.backward()
    assert x.grad.dtype == dtype


# -- gradcheck catches a wrong backward ------------------------------------------------
def wrong_square(x):
    """y = x^2 with a deliberately wrong backward (x instead of 2x)."""
    return Tensor.from_op(x.data ** 2, (x,), lambda g: (g * x.data,), "wrong_square")


def off_by_one_entry(x):
    """Correct gradient except in one entry: only the elementwise check localises it."""
    def vjp(g):
        gx = 2 * x.data * g
        gx.reshape(-1)[3] *= 1.01
        return (gx,)
    return Tensor.from_op(x.data ** 2, (x,), vjp, "off_by_one_entry")


def test_gradcheck_catches_a_wrong_backward():
    with pytest.raises(GradcheckError, match="directional"):
        gradcheck(wrong_square, [rand(3, 4)])


def test_gradcheck_names_the_wrong_entry():
    with pytest.raises(GradcheckError, match=r"inputs\[0\]\[0, 3\]"):
        gradcheck(off_by_one_entry, [rand(2, 5)], n_directions=0)


def test_gradcheck_passes_the_right_backward():
    assert gradcheck(lambda x: x ** 2, [rand(3, 4)])


# -- bad inputs --------------------------------------------------------------------------
def test_bad_inputs_raise_clear_errors():
    with pytest.raises(TypeError, match="float32 or float64"):
        Tensor(np.arange(3))
    with pytest.raises(ValueError, match=r"shapes \(2, 3\) and \(4,\) do not broadcast"):
        ag.add(Tensor(np.ones((2, 3))), Tensor(np.ones(4)))
    with pytest.raises(ValueError, match="inner dimensions"):
        ag.matmul(Tensor(np.ones((2, 3))), Tensor(np.ones((4, 2))))
    with pytest.raises(TypeError, match="mix dtypes"):
        ag.add(Tensor(np.ones(2, np.float32)), Tensor(np.ones(2, np.float64)))
    with pytest.raises(ValueError, match="cannot reshape"):
        ag.reshape(Tensor(np.ones(6)), (4, 2))
    with pytest.raises(ValueError, match="axis 3 is out of range"):
        ag.sum(Tensor(np.ones((2, 2))), axis=3)
    with pytest.raises(ValueError, match="log_softmax: axis 2 is out of range"):
        ag.log_softmax(Tensor(np.ones((2, 2))), axis=2)
    with pytest.raises(TypeError, match="log_softmax: axis must be one int"):
        ag.log_softmax(Tensor(np.ones((2, 2))), axis=(0, 1))
    with pytest.raises(TypeError, match="float64"):
        gradcheck(lambda x: x, [np.ones(3, np.float32)])
    with pytest.raises(ValueError, match="single-element"):
        Tensor(np.ones(3), requires_grad=True).__mul__(2).backward()
