"""The fused LSTM sequence op: gradients, agreement with a cell composed of basic ops,
errors."""
import numpy as np
import pytest

from minid3rqn.autograd.elementwise import sigmoid, tanh
from minid3rqn.autograd.engine import Tensor, reshape
from minid3rqn.autograd.gradcheck import gradcheck
from minid3rqn.autograd.lstm import lstm
from minid3rqn.autograd.shape import concat, stack

pytestmark = pytest.mark.lstm


def _params(rng, batch, in_size, hidden, steps, dtype=np.float64):
    """x, h0, c0, W_ih, W_hh, b with a non-zero initial state."""
    arrays = [rng.standard_normal((steps, batch, in_size)),
              rng.standard_normal((batch, hidden)), rng.standard_normal((batch, hidden)),
              0.5 * rng.standard_normal((4 * hidden, in_size)),
              0.5 * rng.standard_normal((4 * hidden, hidden)),
              0.5 * rng.standard_normal(4 * hidden)]
    return [a.astype(dtype) for a in arrays]


def lstm_cell_reference(x, h, c, weight_ih, weight_hh, bias):
    """One LSTM step composed of basic ops (the engine differentiates it): every line is
    a formula of ``autograd.lstm``'s module docstring."""
    hidden = c.shape[-1]
    z = x @ weight_ih.T + h @ weight_hh.T + bias
    i = sigmoid(z[:, :hidden])
    f = sigmoid(z[:, hidden:2 * hidden])
    g = tanh(z[:, 2 * hidden:3 * hidden])
    o = sigmoid(z[:, 3 * hidden:])
    c_new = f * c + i * g
    return o * tanh(c_new), c_new


def _lstm_joined(*t):
    outputs, (h_last, c_last) = lstm(*t)
    steps, batch, hidden = outputs.shape
    return concat([reshape(outputs, (steps * batch, hidden)), h_last, c_last], axis=0)


# -- gradient checks -------------------------------------------------------------------
@pytest.mark.parametrize("steps", [1, 3, 4])
@pytest.mark.parametrize("with_bias", [True, False])
def test_lstm_sequence_gradcheck(steps, with_bias):
    arrays = _params(np.random.default_rng(steps), batch=2, in_size=3, hidden=2, steps=steps)
    if not with_bias:
        arrays = arrays[:5]
    assert gradcheck(_lstm_joined, arrays)


def test_lstm_gradcheck_larger_directional_only():
    arrays = _params(np.random.default_rng(7), batch=3, in_size=5, hidden=4, steps=4)
    assert gradcheck(_lstm_joined, arrays, elementwise=False, n_directions=4)


def test_lstm_gradcheck_only_final_state():
    arrays = _params(np.random.default_rng(8), batch=2, in_size=2, hidden=3, steps=3)
    assert gradcheck(lambda *t: lstm(*t)[1][1], arrays)


def test_lstm_gradcheck_some_inputs_constant():
    arrays = _params(np.random.default_rng(9), batch=2, in_size=3, hidden=2, steps=3)
    assert gradcheck(_lstm_joined, arrays, check_inputs=[0, 4])
    assert gradcheck(_lstm_joined, arrays, check_inputs=[1, 2])


# -- agreement with the composed reference -------------------------------------------------
def _values_and_grads(fn, arrays, covectors):
    tensors = [Tensor(a.copy(), requires_grad=True) for a in arrays]
    outs = fn(*tensors)
    total = sum((o * u).sum() for o, u in zip(outs, covectors))
    total.backward()
    return [o.data for o in outs], [t.grad for t in tensors]


@pytest.mark.parametrize("steps", [4, 1])
def test_fused_sequence_matches_unrolled_reference_cell(steps):
    rng = np.random.default_rng(2)
    batch, hidden = 3, 5
    arrays = _params(rng, batch=batch, in_size=6, hidden=hidden, steps=steps)
    covectors = [rng.standard_normal((steps, batch, hidden)),
                 rng.standard_normal((batch, hidden)), rng.standard_normal((batch, hidden))]

    def fused(*t):
        outputs, (h, c) = lstm(*t)
        return outputs, h, c

    def unrolled(x, h, c, w_ih, w_hh, b):
        hs = []
        for t in range(steps):
            h, c = lstm_cell_reference(x[t], h, c, w_ih, w_hh, b)
            hs.append(h)
        return stack(hs, axis=0), h, c

    values, grads = _values_and_grads(fused, arrays, covectors)
    ref_values, ref_grads = _values_and_grads(unrolled, arrays, covectors)
    for a, b in zip(values + grads, ref_values + ref_grads):
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-12)


def test_float32_is_preserved_and_zero_initial_state_default():
    rng = np.random.default_rng(3)
    x, h0, c0, w_ih, w_hh, b = _params(rng, batch=2, in_size=3, hidden=4, steps=3,
                                       dtype=np.float32)
    x, w_ih = Tensor(x, requires_grad=True), Tensor(w_ih, requires_grad=True)
    outputs, (h, c) = lstm(x, None, None, w_ih, w_hh, b)
    assert outputs.dtype == h.dtype == c.dtype == np.float32
    zeros = np.zeros((2, 4), np.float32)
    expected, _ = lstm(x.data, zeros, zeros, w_ih.data, w_hh, b)
    np.testing.assert_array_equal(outputs.data, expected.data)
    np.testing.assert_array_equal(h.data, outputs.data[-1])
    (outputs.sum() + c.sum()).backward()
    assert x.grad.dtype == np.float32 and w_ih.grad.dtype == np.float32


# -- bad inputs --------------------------------------------------------------------------
def test_bad_inputs_raise_clear_errors():
    x, h, c, w_ih, w_hh, b = _params(np.random.default_rng(4), batch=2, in_size=3, hidden=2,
                                     steps=3)
    cases = [
        ((x[None], h, c, w_ih, w_hh, b), ValueError, "x must be"),
        ((x[..., :2], h, c, w_ih, w_hh, b), ValueError, "x must have shape"),
        ((x, h[:, :1], c, w_ih, w_hh, b), ValueError, "h"),
        ((x, h, c[:1], w_ih, w_hh, b), ValueError, "c"),
        ((x, h, c, w_ih[:4], w_hh, b), ValueError, "weight_ih must have 4H"),
        ((x, h, c, w_ih, w_hh[:6], b), ValueError, "weight_hh must have shape"),
        ((x, h, c, w_ih[0], w_hh, b), ValueError, "weight_ih must be 2-D"),
        ((x, h, c, w_ih, w_hh, b[:4]), ValueError, "bias must have shape"),
        ((x.astype(np.int64), h, c, w_ih, w_hh, b), TypeError, "x must hold float"),
        ((x, h, c, w_ih, w_hh.astype(np.int32), b), TypeError, "weight_hh must hold float"),
        ((x.astype(np.float32), h, c, w_ih, w_hh, b), TypeError, "mix dtypes"),
    ]
    for args, error, message in cases:
        with pytest.raises(error, match=message):
            lstm(*args)
    with pytest.raises(ValueError, match="at least one time step"):
        lstm(x[:0], h, c, w_ih, w_hh, b)
    with pytest.raises(ValueError, match="h0 must have shape"):
        lstm(x, h[:1], c, w_ih, w_hh, b)
