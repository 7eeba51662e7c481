"""The LSTM: a fused cell and a fused sequence op, each with a hand-derived backward.

Gates follow PyTorch (``torch.nn.LSTM``), in the order (i, f, g, o)::

    z = x W_ih^T + h W_hh^T + b                       (B, 4H), split into four (B, H)
    i = sigmoid(z_i)   f = sigmoid(z_f)   g = tanh(z_g)   o = sigmoid(z_o)
    c' = f * c + i * g
    h' = o * tanh(c')

Shapes: x (B, I), h and c (B, H), W_ih (4H, I), W_hh (4H, H), b (4H,).
PyTorch keeps two biases, ``b_ih`` and ``b_hh``; they only ever appear summed, so we
keep one: ``b = b_ih + b_hh``.

Backward through one step. Given dh' and dc' (the gradient arriving at c' from
outside, e.g. from the next step), with tc = tanh(c')::

    do  = dh' * tc
    dc  = dc' + dh' * o * (1 - tc^2)          total gradient at c'
    di  = dc * g      df = dc * c      dg = dc * i
    dz  = [di * i(1-i), df * f(1-f), dg * (1 - g^2), do * o(1-o)]
    dx  = dz W_ih      dh = dz W_hh      dc_prev = dc * f
    dW_ih = dz^T x     dW_hh = dz^T h    db = sum_batch dz

Backprop through time (``lstm``) runs that step from t = T down to 1, carrying dh and
dc_prev into the previous step. The products that do not depend on the recurrence are
done once for the whole sequence: x W_ih^T before the loop, and dx, dW_ih, dW_hh, db
after it, each a single GEMM over the (T*B) rows.

Two outputs from one op: the engine's ops return one Tensor, so the fused ops return
``[h, c]`` joined along the last axis, and two thin slicing views hand out h and c.
Gradients reaching h and c meet again at the joined tensor (the engine sums them).
"""
from __future__ import annotations

import numpy as np

from .engine import (FLOAT_DTYPES, Tensor, add, as_tensor, check_same_dtype, matmul, mul,
                     transpose)
from .elementwise import _stable_sigmoid, sigmoid, tanh


# -- helpers -------------------------------------------------------------------------
def _arg(x, name: str, op: str) -> Tensor:
    """``x`` as a Tensor, refusing non-float arrays with a message naming ``name``."""
    if not isinstance(x, Tensor):
        x = np.asarray(x)
        if x.dtype not in FLOAT_DTYPES:
            raise TypeError(f"{op}: {name} must hold float32 or float64 values; got "
                            f"dtype {x.dtype}")
    return as_tensor(x)


def _check_ndim(t: Tensor, ndim: int, name: str, op: str, layout: str) -> None:
    if t.ndim != ndim:
        raise ValueError(f"{op}: {name} must be {ndim}-D {layout}; got shape {t.shape}")


def _check_shape(t: Tensor, shape: tuple, name: str, op: str, why: str) -> None:
    if t.shape != shape:
        raise ValueError(f"{op}: {name} must have shape {shape} ({why}); got {t.shape}")


def _check_weights(weight_ih: Tensor, weight_hh: Tensor, bias, op: str) -> tuple[int, int]:
    """Validate W_ih (4H, I), W_hh (4H, H), b (4H,); return (I, H)."""
    _check_ndim(weight_ih, 2, "weight_ih", op, "(4H, I)")
    _check_ndim(weight_hh, 2, "weight_hh", op, "(4H, H)")
    four_h, hidden = weight_hh.shape
    if four_h != 4 * hidden:
        raise ValueError(f"{op}: weight_hh must have shape (4H, H); got {weight_hh.shape} "
                         f"({four_h} rows != 4 * {hidden})")
    if weight_ih.shape[0] != four_h:
        raise ValueError(f"{op}: weight_ih must have 4H = {four_h} rows (like weight_hh "
                         f"{weight_hh.shape}); got {weight_ih.shape}")
    if bias is not None:
        _check_shape(bias, (four_h,), "bias", op, "4H, the sum b_ih + b_hh of PyTorch")
    return weight_ih.shape[1], hidden


def _slice_last(x: Tensor, start: int, stop: int, name: str, lead=()) -> Tensor:
    """y = x[lead..., start:stop] (a basic slice);  dL/dx = g placed there, zeros elsewhere.

    Used to split a fused op's joined ``[h, c]`` output. Basic slices never repeat an
    entry, so the scatter is a plain assignment (no ``np.add.at``).
    """
    index = tuple(lead) + (Ellipsis, slice(start, stop))

    def vjp(g):
        gx = np.zeros_like(x.data)
        gx[index] = g
        return (gx,)

    return Tensor.from_op(x.data[index].copy(), (x,), vjp, name)


def _gates(z: np.ndarray, hidden: int) -> np.ndarray:
    """Activate the pre-activations z (..., 4H) in place: sigmoid on i, f, o; tanh on g."""
    z[..., :2 * hidden] = _stable_sigmoid(z[..., :2 * hidden])
    z[..., 2 * hidden:3 * hidden] = np.tanh(z[..., 2 * hidden:3 * hidden])
    z[..., 3 * hidden:] = _stable_sigmoid(z[..., 3 * hidden:])
    return z


def _gate_grads(dc: np.ndarray, do: np.ndarray, gates: np.ndarray, c_prev: np.ndarray,
                hidden: int) -> np.ndarray:
    """dz = [dc*g * i(1-i), dc*c * f(1-f), dc*i * (1-g^2), do * o(1-o)]  (..., 4H)."""
    i, f = gates[..., :hidden], gates[..., hidden:2 * hidden]
    g, o = gates[..., 2 * hidden:3 * hidden], gates[..., 3 * hidden:]
    dz = np.empty_like(gates)
    dz[..., :hidden] = dc * g * i * (1 - i)
    dz[..., hidden:2 * hidden] = dc * c_prev * f * (1 - f)
    dz[..., 2 * hidden:3 * hidden] = dc * i * (1 - g * g)
    dz[..., 3 * hidden:] = do * o * (1 - o)
    return dz


# -- one step ------------------------------------------------------------------------
def lstm_cell(x, h, c, weight_ih, weight_hh, bias=None) -> tuple[Tensor, Tensor]:
    """One LSTM step, fused: ``(h', c') = cell(x, (h, c))`` (math in the module docstring).

    Args:
        x: (B, I) input.   h, c: (B, H) previous hidden and cell state.
        weight_ih: (4H, I).   weight_hh: (4H, H).   bias: (4H,) or None;
            ``b = b_ih + b_hh`` of ``torch.nn.LSTMCell``.

    Returns:
        (h', c'), each (B, H).
    """
    op = "lstm_cell"
    x, h, c = _arg(x, "x", op), _arg(h, "h", op), _arg(c, "c", op)
    weight_ih, weight_hh = _arg(weight_ih, "weight_ih", op), _arg(weight_hh, "weight_hh", op)
    bias = None if bias is None else _arg(bias, "bias", op)
    parents = [x, h, c, weight_ih, weight_hh] + ([bias] if bias is not None else [])
    check_same_dtype(parents, op)
    in_size, hidden = _check_weights(weight_ih, weight_hh, bias, op)
    _check_ndim(x, 2, "x", op, "(B, I)")
    batch = x.shape[0]
    _check_shape(x, (batch, in_size), "x", op, "(B, I) with I = weight_ih.shape[1]")
    _check_shape(h, (batch, hidden), "h", op, "(B, H) with H = weight_hh.shape[1]")
    _check_shape(c, (batch, hidden), "c", op, "(B, H) with H = weight_hh.shape[1]")

    # forward
    z = x.data @ weight_ih.data.T
    z += h.data @ weight_hh.data.T
    if bias is not None:
        z += bias.data
    gates = _gates(z, hidden)
    i, f = gates[:, :hidden], gates[:, hidden:2 * hidden]
    g, o = gates[:, 2 * hidden:3 * hidden], gates[:, 3 * hidden:]
    c_new = f * c.data + i * g
    tc = np.tanh(c_new)
    hc = np.concatenate([o * tc, c_new], axis=1)

    def vjp(ghc):
        gh, gc = ghc[:, :hidden], ghc[:, hidden:]
        do = gh * tc
        dc = gc + gh * o * (1 - tc * tc)
        dz = _gate_grads(dc, do, gates, c.data, hidden)
        return (dz @ weight_ih.data if x.requires_grad else None,
                dz @ weight_hh.data if h.requires_grad else None,
                dc * f if c.requires_grad else None,
                dz.T @ x.data if weight_ih.requires_grad else None,
                dz.T @ h.data if weight_hh.requires_grad else None,
                *((dz.sum(axis=0),) if bias is not None else ()))

    joined = Tensor.from_op(hc, parents, vjp, op)
    return (_slice_last(joined, 0, hidden, "lstm_cell.h"),
            _slice_last(joined, hidden, 2 * hidden, "lstm_cell.c"))


def lstm_cell_reference(x, h, c, weight_ih, weight_hh, bias=None) -> tuple[Tensor, Tensor]:
    """The same step as ``lstm_cell``, composed of basic ops (the engine differentiates it).

    Slower and deeper, but every line is the textbook formula; the tests check that the
    fused cell agrees with it in values and gradients.
    """
    x, h, c = as_tensor(x), as_tensor(h), as_tensor(c)
    hidden = c.shape[-1]
    z = add(matmul(x, transpose(as_tensor(weight_ih))),
            matmul(h, transpose(as_tensor(weight_hh))))
    if bias is not None:
        z = add(z, bias)
    i = sigmoid(z[:, :hidden])
    f = sigmoid(z[:, hidden:2 * hidden])
    g = tanh(z[:, 2 * hidden:3 * hidden])
    o = sigmoid(z[:, 3 * hidden:])
    c_new = add(mul(f, c), mul(i, g))
    h_new = mul(o, tanh(c_new))
    return h_new, c_new


# -- a whole sequence ----------------------------------------------------------------
def lstm(x, h0, c0, weight_ih, weight_hh, bias=None) -> tuple[Tensor, tuple[Tensor, Tensor]]:
    """A one-layer LSTM over a sequence, fused, with backprop through time.

    Like ``torch.nn.LSTM`` (one layer, ``batch_first=False``) with ``bias = b_ih + b_hh``.

    Args:
        x: (T, B, I) inputs, time first.
        h0, c0: (B, H) initial state, or None for zeros.
        weight_ih: (4H, I).   weight_hh: (4H, H).   bias: (4H,) or None.

    Returns:
        (outputs, (h_T, c_T)): outputs (T, B, H) holds h_1 .. h_T; h_T, c_T are (B, H).

    Forward: Z_x = X W_ih^T + b for all T*B rows in one GEMM; then per step
    z_t = Z_x[t] + h_{t-1} W_hh^T and the cell update. Backward: the per-step formulas of
    the module docstring from t = T to 1 (only dz_t W_hh stays in the loop); then
    dX = dZ W_ih, dW_ih = dZ^T X, dW_hh = dZ^T [h_0 .. h_{T-1}], db = sum dZ, one GEMM each.
    """
    op = "lstm"
    x = _arg(x, "x", op)
    weight_ih, weight_hh = _arg(weight_ih, "weight_ih", op), _arg(weight_hh, "weight_hh", op)
    bias = None if bias is None else _arg(bias, "bias", op)
    in_size, hidden = _check_weights(weight_ih, weight_hh, bias, op)
    _check_ndim(x, 3, "x", op, "(T, B, I)")
    steps, batch = x.shape[0], x.shape[1]
    _check_shape(x, (steps, batch, in_size), "x", op, "(T, B, I) with I = weight_ih.shape[1]")
    if steps == 0:
        raise ValueError(f"{op}: x must hold at least one time step; got shape {x.shape}")
    dtype = x.dtype
    h0 = Tensor(np.zeros((batch, hidden), dtype)) if h0 is None else _arg(h0, "h0", op)
    c0 = Tensor(np.zeros((batch, hidden), dtype)) if c0 is None else _arg(c0, "c0", op)
    _check_shape(h0, (batch, hidden), "h0", op, "(B, H) with H = weight_hh.shape[1]")
    _check_shape(c0, (batch, hidden), "c0", op, "(B, H) with H = weight_hh.shape[1]")
    parents = [x, h0, c0, weight_ih, weight_hh] + ([bias] if bias is not None else [])
    check_same_dtype(parents, op)

    # forward: gates (T, B, 4H); hs[t] = h_t and cs[t] = c_t for t = 0..T
    w_ih, w_hh = weight_ih.data, weight_hh.data
    gates = (x.data.reshape(steps * batch, in_size) @ w_ih.T).reshape(steps, batch, 4 * hidden)
    if bias is not None:
        gates += bias.data
    hs = np.empty((steps + 1, batch, hidden), dtype)
    cs = np.empty((steps + 1, batch, hidden), dtype)
    hs[0], cs[0] = h0.data, c0.data
    for t in range(steps):
        zt = gates[t]
        zt += hs[t] @ w_hh.T
        _gates(zt, hidden)
        i, f = zt[:, :hidden], zt[:, hidden:2 * hidden]
        g, o = zt[:, 2 * hidden:3 * hidden], zt[:, 3 * hidden:]
        cs[t + 1] = f * cs[t] + i * g
        hs[t + 1] = o * np.tanh(cs[t + 1])
    tcs = np.tanh(cs[1:])
    joined = np.concatenate([hs[1:], cs[1:]], axis=2)        # (T, B, 2H): [h_t, c_t]

    def vjp(ghc):
        gh, gc = ghc[..., :hidden], ghc[..., hidden:]
        dzs = np.empty_like(gates)
        dh = np.zeros((batch, hidden), dtype)                 # from step t+1 into h_t
        dc_next = np.zeros((batch, hidden), dtype)            # from step t+1 into c_t
        for t in range(steps - 1, -1, -1):
            zt = gates[t]
            f, o = zt[:, hidden:2 * hidden], zt[:, 3 * hidden:]
            dh = dh + gh[t]
            do = dh * tcs[t]
            dc = gc[t] + dc_next + dh * o * (1 - tcs[t] * tcs[t])
            dzs[t] = _gate_grads(dc, do, zt, cs[t], hidden)
            dh = dzs[t] @ w_hh
            dc_next = dc * f
        dz = dzs.reshape(steps * batch, 4 * hidden)
        return (
            (dz @ w_ih).reshape(x.shape) if x.requires_grad else None,
            dh if h0.requires_grad else None,
            dc_next if c0.requires_grad else None,
            dz.T @ x.data.reshape(steps * batch, in_size) if weight_ih.requires_grad else None,
            dz.T @ hs[:-1].reshape(steps * batch, hidden) if weight_hh.requires_grad else None,
            *((dz.sum(axis=0),) if bias is not None else ()))

    out = Tensor.from_op(joined, parents, vjp, op)
    outputs = _slice_last(out, 0, hidden, "lstm.outputs")
    h_last = _slice_last(out, 0, hidden, "lstm.h_T", lead=(steps - 1,))
    c_last = _slice_last(out, hidden, 2 * hidden, "lstm.c_T", lead=(steps - 1,))
    return outputs, (h_last, c_last)


__all__ = ["lstm_cell", "lstm", "lstm_cell_reference"]
