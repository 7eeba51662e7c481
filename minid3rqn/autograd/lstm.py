"""The LSTM: one fused sequence op with a hand-derived backward (backprop through time).

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

Several outputs from one op: the engine's ops return one Tensor, so ``lstm`` returns
``[h_t, c_t]`` joined along the last axis, and ``crop`` views hand out the outputs and
the final state. Gradients reaching them meet again at the joined tensor (the engine
sums them).
"""
from __future__ import annotations

import numpy as np

from . import kernels
from .elementwise import _stable_sigmoid
from .engine import Tensor, check_same_dtype, float_tensor, is_grad_enabled
from .shape import crop


# -- helpers -------------------------------------------------------------------------
def _check_shape(t: Tensor, shape: tuple, name: str, why: str) -> None:
    if t.shape != shape:
        raise ValueError(f"lstm: {name} must have shape {shape} ({why}); got {t.shape}")


def _check_weights(weight_ih: Tensor, weight_hh: Tensor, bias) -> tuple[int, int]:
    """Validate W_ih (4H, I), W_hh (4H, H), b (4H,); return (I, H)."""
    for name, w, layout in (("weight_ih", weight_ih, "(4H, I)"),
                            ("weight_hh", weight_hh, "(4H, H)")):
        if w.ndim != 2:
            raise ValueError(f"lstm: {name} must be 2-D {layout}; got shape {w.shape}")
    four_h, hidden = weight_hh.shape
    if four_h != 4 * hidden:
        raise ValueError(f"lstm: weight_hh must have shape (4H, H); got {weight_hh.shape} "
                         f"({four_h} rows != 4 * {hidden})")
    if weight_ih.shape[0] != four_h:
        raise ValueError(f"lstm: weight_ih must have 4H = {four_h} rows (like weight_hh "
                         f"{weight_hh.shape}); got {weight_ih.shape}")
    if bias is not None:
        _check_shape(bias, (four_h,), "bias", "4H, the sum b_ih + b_hh of PyTorch")
    return weight_ih.shape[1], hidden


def _check_inputs(x, h0, c0, weight_ih, weight_hh, bias) -> list[Tensor]:
    """The arguments of ``lstm`` as Tensors (zeros for a None state), validated."""
    x = float_tensor(x, "x", "lstm")
    weight_ih = float_tensor(weight_ih, "weight_ih", "lstm")
    weight_hh = float_tensor(weight_hh, "weight_hh", "lstm")
    bias = None if bias is None else float_tensor(bias, "bias", "lstm")
    in_size, hidden = _check_weights(weight_ih, weight_hh, bias)
    if x.ndim != 3:
        raise ValueError(f"lstm: x must be 3-D (T, B, I); got shape {x.shape}")
    steps, batch = x.shape[0], x.shape[1]
    _check_shape(x, (steps, batch, in_size), "x", "(T, B, I) with I = weight_ih.shape[1]")
    if steps == 0:
        raise ValueError(f"lstm: x must hold at least one time step; got shape {x.shape}")
    state = []
    for name, s in (("h0", h0), ("c0", c0)):
        s = Tensor(np.zeros((batch, hidden), x.dtype)) if s is None else float_tensor(
            s, name, "lstm")
        _check_shape(s, (batch, hidden), name, "(B, H) with H = weight_hh.shape[1]")
        state.append(s)
    parents = [x, *state, weight_ih, weight_hh] + ([bias] if bias is not None else [])
    check_same_dtype(parents, "lstm")
    return parents


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


def _backward(ghc, gates, cs, tcs, w_hh):
    """Backprop through time: the module docstring's step from t = T down to 1.

    ghc (T, B, 2H) the gradient at the joined [h_t, c_t]; gates (T, B, 4H) activated;
    cs (T + 1, B, H) the cell states c_0..c_T; tcs = tanh(cs[1:]). Returns
    (dZ (T B, 4H), dL/dh_0, dL/dc_0).
    """
    steps, batch, four_h = gates.shape
    hidden = four_h // 4
    gh, gc = ghc[..., :hidden], ghc[..., hidden:]
    dzs = np.empty_like(gates)
    dh = np.zeros((batch, hidden), gates.dtype)                 # from step t+1 into h_t
    dc_next = np.zeros((batch, hidden), gates.dtype)            # from step t+1 into c_t
    for t in range(steps - 1, -1, -1):
        zt = gates[t]
        f, o = zt[:, hidden:2 * hidden], zt[:, 3 * hidden:]
        dh = dh + gh[t]
        do = dh * tcs[t]
        dc = gc[t] + dc_next + dh * o * (1 - tcs[t] * tcs[t])
        dzs[t] = _gate_grads(dc, do, zt, cs[t], hidden)
        dh = dzs[t] @ w_hh
        dc_next = dc * f
    return dzs.reshape(steps * batch, four_h), dh, dc_next


# -- the sequence op -----------------------------------------------------------------
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
    z_t = Z_x[t] + h_{t-1} W_hh^T and the cell update. Backward (``_backward``): the
    per-step formulas of the module docstring from t = T to 1 (only dz_t W_hh stays in
    the loop); then dX = dZ W_ih, dW_ih = dZ^T X, dW_hh = dZ^T [h_0 .. h_{T-1}],
    db = sum dZ, one GEMM each.
    """
    parents = _check_inputs(x, h0, c0, weight_ih, weight_hh, bias)
    x, h0, c0, weight_ih, weight_hh, *b = parents       # b: [bias] or []
    steps, batch, in_size = x.shape
    hidden, dtype = weight_hh.shape[1], x.dtype

    # forward: gates (T, B, 4H); hs[t] = h_t and cs[t] = c_t for t = 0..T
    w_ih, w_hh = weight_ih.data, weight_hh.data
    gates = kernels.times_transposed(x.data.reshape(steps * batch, in_size), weight_ih)
    gates = gates.reshape(steps, batch, 4 * hidden)
    if b:
        gates += b[0].data
    hs = np.empty((steps + 1, batch, hidden), dtype)
    cs = np.empty((steps + 1, batch, hidden), dtype)
    hs[0], cs[0] = h0.data, c0.data
    for t in range(steps):
        zt = gates[t]
        zt += kernels.times_transposed(hs[t], weight_hh)
        _gates(zt, hidden)
        i, f = zt[:, :hidden], zt[:, hidden:2 * hidden]
        g, o = zt[:, 2 * hidden:3 * hidden], zt[:, 3 * hidden:]
        cs[t + 1] = f * cs[t] + i * g
        hs[t + 1] = o * np.tanh(cs[t + 1])
    if not (is_grad_enabled() and any(p.requires_grad for p in parents)):
        return Tensor(hs[1:]), (Tensor(hs[-1]), Tensor(cs[-1]))      # no graph to keep
    tcs = np.tanh(cs[1:])
    joined = np.concatenate([hs[1:], cs[1:]], axis=2)        # (T, B, 2H): [h_t, c_t]

    def vjp(ghc):
        dz, dh0, dc0 = _backward(ghc, gates, cs, tcs, w_hh)
        return (
            (dz @ w_ih).reshape(x.shape) if x.requires_grad else None,
            dh0 if h0.requires_grad else None,
            dc0 if c0.requires_grad else None,
            dz.T @ x.data.reshape(steps * batch, in_size) if weight_ih.requires_grad else None,
            dz.T @ hs[:-1].reshape(steps * batch, hidden) if weight_hh.requires_grad else None,
            *((dz.sum(axis=0),) if b else ()))

    out = Tensor.from_op(joined, parents, vjp, "lstm")
    h_part, c_part = slice(0, hidden), slice(hidden, 2 * hidden)
    return crop(out, (Ellipsis, h_part)), (crop(out, (steps - 1, Ellipsis, h_part)),
                                           crop(out, (steps - 1, Ellipsis, c_part)))
