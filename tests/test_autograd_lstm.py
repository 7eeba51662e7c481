"""The fused LSTM cell and sequence op: gradients, agreement with the composed cell, errors."""
import numpy as np
import pytest

from minid3rqn.autograd.engine import Tensor, reshape
from minid3rqn.autograd.gradcheck import gradcheck
from minid3rqn.autograd.lstm import lstm, lstm_cell, lstm_cell_reference
from minid3rqn.autograd.shape import concat

pytestmark = pytest.mark.lstm


def _params(rng, batch, in_size, hidden, steps=None, dtype=np.float64):
    """x, h0, c0, W_ih, W_hh, b with a non-zero initial state."""
    x_shape = (batch, in_size) if steps is None else (steps, batch, in_size)
    arrays = [rng.standard_normal(x_shape), rng.standard_normal((batch, hidden)),
              rng.standard_normal((batch, hidden)),
              0.5 * rng.standard_normal((4 * hidden, in_size)),
              0.5 * rng.standard_normal((4 * hidden, hidden)),
              0.5 * rng.standard_normal(4 * hidden)]
    return [a.astype(dtype) for a in arrays]


def _cell_joined(cell):
    return lambda *t: concat(list(cell(*t)), axis=1)


def _lstm_joined(*t):
    outputs, (h_last, c_last) = lstm(*t)
    steps, batch, hidden = outputs.shape
    return concat([reshape(outputs, (steps * batch, hidden)), h_last, c_last], axis=0)


# -- gradient checks -------------------------------------------------------------------
@pytest.mark.parametrize("with_bias", [True, False])
def test_lstm_cell_gradcheck(with_bias):
    arrays = _params(np.random.default_rng(0), batch=2, in_size=3, hidden=2)
    if not with_bias:
        arrays = arrays[:5]
    assert gradcheck(_cell_joined(lstm_cell), arrays)


@pytest.mark.parametrize("steps", [3, 4])
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
    assert gradcheck(_cell_joined(lstm_cell), [a[0] if i == 0 else a for i, a in
                                               enumerate(arrays)], check_inputs=[1, 2])


# -- agreement with the composed reference -------------------------------------------------
def _values_and_grads(fn, arrays, covectors):
    tensors = [Tensor(a.copy(), requires_grad=True) for a in arrays]
    outs = fn(*tensors)
    total = sum((o * u).sum() for o, u in zip(outs, covectors))
    total.backward()
    return [o.data for o in outs], [t.grad for t in tensors]


def test_fused_cell_matches_reference():
    rng = np.random.default_rng(1)
    arrays = _params(rng, batch=4, in_size=5, hidden=3)
    covectors = [rng.standard_normal((4, 3)) for _ in range(2)]
    values, grads = _values_and_grads(lstm_cell, arrays, covectors)
    ref_values, ref_grads = _values_and_grads(lstm_cell_reference, arrays, covectors)
    for a, b in zip(values + grads, ref_values + ref_grads):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_fused_sequence_matches_unrolled_reference_cell():
    rng = np.random.default_rng(2)
    steps, batch, hidden = 4, 3, 5
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
        from minid3rqn.autograd.shape import stack
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
    h1, c1 = lstm_cell(x[0], h0, c0, w_ih, w_hh, b)
    assert h1.dtype == c1.dtype == np.float32


# -- bad inputs --------------------------------------------------------------------------
def _good(steps=None):
    return _params(np.random.default_rng(4), batch=2, in_size=3, hidden=2, steps=steps)


@pytest.mark.parametrize("fn, steps", [(lstm_cell, None), (lstm, 3)])
def test_bad_inputs_raise_clear_errors(fn, steps):
    x, h, c, w_ih, w_hh, b = _good(steps)
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
            fn(*args)


def test_bad_sequence_length():
    x, h, c, w_ih, w_hh, b = _good(steps=3)
    with pytest.raises(ValueError, match="at least one time step"):
        lstm(x[:0], h, c, w_ih, w_hh, b)
    with pytest.raises(ValueError, match="h0 must have shape"):
        lstm(x, h[:1], c, w_ih, w_hh, b)
