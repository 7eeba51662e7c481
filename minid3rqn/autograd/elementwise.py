"""Elementwise ops and matmul. Each: forward, then its vector-Jacobian product.

Notation: ``g = dL/dy`` is the gradient arriving at the output ``y``. Binary ops
broadcast like NumPy; ``unbroadcast`` sums the gradient back to each input's shape.
"""
from __future__ import annotations

import numpy as np

from .engine import Tensor, as_tensor, check_same_dtype, unbroadcast


def _pair(a, b, op: str) -> tuple[Tensor, Tensor]:
    if isinstance(a, Tensor):
        b = as_tensor(b, like=a)
    elif isinstance(b, Tensor):
        a = as_tensor(a, like=b)
    else:
        a, b = as_tensor(a), as_tensor(b)
    check_same_dtype((a, b), op)
    try:
        np.broadcast_shapes(a.shape, b.shape)
    except ValueError:
        raise ValueError(f"{op}: shapes {a.shape} and {b.shape} do not broadcast") from None
    return a, b


# -- arithmetic ----------------------------------------------------------------------
def add(a, b) -> Tensor:
    """y = a + b;  dy/da = 1, dy/db = 1."""
    a, b = _pair(a, b, "add")
    return Tensor.from_op(a.data + b.data, (a, b),
                          lambda g: (unbroadcast(g, a.shape), unbroadcast(g, b.shape)), "add")


def sub(a, b) -> Tensor:
    """y = a - b;  dy/da = 1, dy/db = -1."""
    a, b = _pair(a, b, "sub")
    return Tensor.from_op(a.data - b.data, (a, b),
                          lambda g: (unbroadcast(g, a.shape), unbroadcast(-g, b.shape)), "sub")


def mul(a, b) -> Tensor:
    """y = a * b;  dy/da = b, dy/db = a."""
    a, b = _pair(a, b, "mul")
    return Tensor.from_op(a.data * b.data, (a, b),
                          lambda g: (unbroadcast(g * b.data, a.shape),
                                     unbroadcast(g * a.data, b.shape)), "mul")


def div(a, b) -> Tensor:
    """y = a / b;  dy/da = 1/b, dy/db = -a/b^2 = -y/b."""
    a, b = _pair(a, b, "div")
    y = a.data / b.data
    return Tensor.from_op(y, (a, b),
                          lambda g: (unbroadcast(g / b.data, a.shape),
                                     unbroadcast(-g * y / b.data, b.shape)), "div")


def neg(x) -> Tensor:
    """y = -x;  dy/dx = -1."""
    x = as_tensor(x)
    return Tensor.from_op(-x.data, (x,), lambda g: (-g,), "neg")


def pow(x, exponent) -> Tensor:
    """y = x^p for a constant p;  dy/dx = p x^(p-1)."""
    x = as_tensor(x)
    if isinstance(exponent, Tensor):
        raise TypeError("pow: exponent must be a Python number (a constant); "
                        "for x^t with a tensor t use exp(t * log(x))")
    p = float(exponent)
    y = x.data ** p
    return Tensor.from_op(y, (x,), lambda g: (g * p * x.data ** (p - 1),), "pow")


def exp(x) -> Tensor:
    """y = e^x;  dy/dx = e^x = y."""
    x = as_tensor(x)
    y = np.exp(x.data)
    return Tensor.from_op(y, (x,), lambda g: (g * y,), "exp")


def log(x) -> Tensor:
    """y = ln x;  dy/dx = 1/x."""
    x = as_tensor(x)
    return Tensor.from_op(np.log(x.data), (x,), lambda g: (g / x.data,), "log")


def sqrt(x) -> Tensor:
    """y = sqrt(x);  dy/dx = 1 / (2 y)."""
    x = as_tensor(x)
    y = np.sqrt(x.data)
    return Tensor.from_op(y, (x,), lambda g: (g / (2 * y),), "sqrt")


def abs(x) -> Tensor:
    """y = |x|;  dy/dx = sign(x) (0 at x = 0, a subgradient)."""
    x = as_tensor(x)
    return Tensor.from_op(np.abs(x.data), (x,), lambda g: (g * np.sign(x.data),), "abs")


def astype(x, dtype) -> Tensor:
    """y = x in another float dtype;  dy/dx = 1 (the gradient converts back)."""
    x = as_tensor(x)
    old = x.dtype
    return Tensor.from_op(x.data.astype(dtype), (x,), lambda g: (g.astype(old),), "astype")


# -- activations -----------------------------------------------------------------------
def relu(x) -> Tensor:
    """y = max(x, 0);  dy/dx = 1 if x > 0 else 0."""
    x = as_tensor(x)
    mask = x.data > 0
    return Tensor.from_op(x.data * mask, (x,), lambda g: (g * mask,), "relu")


def elu(x, alpha: float = 1.0) -> Tensor:
    """y = x if x > 0 else alpha (e^x - 1);  dy/dx = 1 if x > 0 else y + alpha."""
    x = as_tensor(x)
    pos = x.data > 0
    neg_part = alpha * np.expm1(np.minimum(x.data, 0))
    y = np.where(pos, x.data, neg_part)
    return Tensor.from_op(y, (x,), lambda g: (g * np.where(pos, 1, neg_part + alpha),), "elu")


def sigmoid(x) -> Tensor:
    """y = 1 / (1 + e^-x);  dy/dx = y (1 - y). Computed without overflow."""
    x = as_tensor(x)
    y = _stable_sigmoid(x.data)
    return Tensor.from_op(y, (x,), lambda g: (g * y * (1 - y),), "sigmoid")


def _stable_sigmoid(z: np.ndarray) -> np.ndarray:
    e = np.exp(-np.abs(z))
    return np.where(z >= 0, 1 / (1 + e), e / (1 + e)).astype(z.dtype, copy=False)


def tanh(x) -> Tensor:
    """y = tanh x;  dy/dx = 1 - y^2."""
    x = as_tensor(x)
    y = np.tanh(x.data)
    return Tensor.from_op(y, (x,), lambda g: (g * (1 - y * y),), "tanh")


def softplus(x) -> Tensor:
    """y = ln(1 + e^x);  dy/dx = sigmoid(x). Computed as max(x,0) + ln(1 + e^-|x|)."""
    x = as_tensor(x)
    y = np.maximum(x.data, 0) + np.log1p(np.exp(-np.abs(x.data)))
    return Tensor.from_op(y, (x,), lambda g: (g * _stable_sigmoid(x.data),), "softplus")


# -- selection -----------------------------------------------------------------------
def clip(x, low=None, high=None) -> Tensor:
    """y = min(max(x, low), high);  dy/dx = 1 inside (low, high), else 0."""
    x = as_tensor(x)
    if low is None and high is None:
        raise ValueError("clip: give at least one of low and high")
    y = np.clip(x.data, low, high)
    inside = y == x.data
    return Tensor.from_op(y, (x,), lambda g: (g * inside,), "clip")


def where(condition, a, b) -> Tensor:
    """y = a where condition else b;  dy/da = condition, dy/db = not condition."""
    cond = np.asarray(condition.data if isinstance(condition, Tensor) else condition)
    if cond.dtype != bool:
        raise TypeError(f"where: condition must be a boolean array; got {cond.dtype}")
    a, b = _pair(a, b, "where")
    y = np.where(cond, a.data, b.data)
    return Tensor.from_op(y, (a, b),
                          lambda g: (unbroadcast(np.where(cond, g, 0), a.shape),
                                     unbroadcast(np.where(cond, 0, g), b.shape)), "where")


def maximum(a, b) -> Tensor:
    """y = max(a, b);  the gradient goes to the larger (to a on ties)."""
    a, b = _pair(a, b, "maximum")
    return where(a.data >= b.data, a, b)


def minimum(a, b) -> Tensor:
    """y = min(a, b);  the gradient goes to the smaller (to a on ties)."""
    a, b = _pair(a, b, "minimum")
    return where(a.data <= b.data, a, b)


# -- matrix product --------------------------------------------------------------------
def matmul(a, b) -> Tensor:
    """Y = A @ B (batched over leading axes, broadcast like NumPy).

    dL/dA = G @ B^T,  dL/dB = A^T @ G  (then summed over broadcast batch axes).
    Vectors (1-D) are treated as in NumPy: promoted, then the added axis removed.
    """
    a, b = _pair_matmul(a, b)
    y = a.data @ b.data

    def vjp(g):
        ad, bd = a.data, b.data
        if ad.ndim == 1 and bd.ndim == 1:       # dot product: g is a scalar
            return g * bd, g * ad
        if ad.ndim == 1:                        # (k) @ (..., k, n) -> (..., n)
            ga = (g[..., None, :] @ np.swapaxes(bd, -1, -2))[..., 0, :]
            gb = ad[:, None] * g[..., None, :]
            return unbroadcast(ga, a.shape), unbroadcast(gb, b.shape)
        if bd.ndim == 1:                        # (..., m, k) @ (k) -> (..., m)
            ga = g[..., :, None] * bd
            gb = (np.swapaxes(ad, -1, -2) @ g[..., :, None])[..., 0]
            return unbroadcast(ga, a.shape), unbroadcast(gb, b.shape)
        ga = g @ np.swapaxes(bd, -1, -2)
        gb = np.swapaxes(ad, -1, -2) @ g
        return unbroadcast(ga, a.shape), unbroadcast(gb, b.shape)

    return Tensor.from_op(y, (a, b), vjp, "matmul")


def _pair_matmul(a, b) -> tuple[Tensor, Tensor]:
    if isinstance(a, Tensor):
        b = as_tensor(b, like=a)
    else:
        b = as_tensor(b)
        a = as_tensor(a, like=b)
    check_same_dtype((a, b), "matmul")
    if a.ndim == 0 or b.ndim == 0:
        raise ValueError(f"matmul: inputs must have at least 1 dimension; got shapes "
                         f"{a.shape} and {b.shape}")
    k_a = a.shape[-1]
    k_b = b.shape[0] if b.ndim == 1 else b.shape[-2]
    if k_a != k_b:
        raise ValueError(f"matmul: inner dimensions differ: a is {a.shape}, b is "
                         f"{b.shape} ({k_a} != {k_b})")
    return a, b


__all__ = ["add", "sub", "mul", "div", "neg", "pow", "exp", "log", "sqrt", "abs",
           "astype", "relu", "elu", "sigmoid", "tanh", "softplus", "clip", "where",
           "maximum", "minimum", "matmul"]
