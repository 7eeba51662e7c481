"""Elementwise ops beyond the operators. Each: forward, then its vector-Jacobian product.

Notation: ``g = dL/dy`` is the gradient arriving at the output ``y``. Binary ops
broadcast like NumPy; ``unbroadcast`` sums the gradient back to each input's shape.
The arithmetic (+ - * / **), matmul, exp, log, relu and astype sit in engine.py,
beside the Tensor whose operators call them.
"""
from __future__ import annotations

import numpy as np

from . import kernels
from .engine import Tensor, as_tensor, broadcast_pair, unbroadcast


# -- more elementwise functions -------------------------------------------------------
def sqrt(x) -> Tensor:
    """y = sqrt(x);  dy/dx = 1 / (2 y)."""
    x = as_tensor(x)
    y = np.sqrt(x.data)
    return Tensor.from_op(y, (x,), lambda g: (g / (2 * y),), "sqrt")


def abs(x) -> Tensor:
    """y = |x|;  dy/dx = sign(x) (0 at x = 0, a subgradient)."""
    x = as_tensor(x)
    return Tensor.from_op(np.abs(x.data), (x,), lambda g: (g * np.sign(x.data),), "abs")


# -- activations -----------------------------------------------------------------------
def elu(x, alpha: float = 1.0) -> Tensor:
    """y = x if x > 0 else alpha (e^x - 1);  dy/dx = 1 if x > 0 else y + alpha."""
    x = as_tensor(x)
    zeros = kernels.zeros_like_layout(x.data)       # (faster than the scalar 0)
    neg = np.minimum(x.data, zeros)
    np.expm1(neg, out=neg)                          # alpha (e^x - 1) where x <= 0, else 0
    if alpha != 1:
        neg *= alpha
    y = np.maximum(x.data, zeros)                   # x where x > 0, else 0
    y += neg                                        # each entry: itself plus an exact 0

    def vjp(g):
        if alpha == 1:               # min(y, 0) + 1: 1 where y > 0, y + 1 elsewhere
            slope = np.minimum(y, zeros)
            slope += 1
            slope *= g
            return (slope,)
        return (g * np.where(y > 0, 1, y + alpha),)
    return Tensor.from_op(y, (x,), vjp, "elu")


def sigmoid(x) -> Tensor:
    """y = 1 / (1 + e^-x);  dy/dx = y (1 - y). Computed without overflow."""
    x = as_tensor(x)
    y = _stable_sigmoid(x.data)
    return Tensor.from_op(y, (x,), lambda g: (g * y * (1 - y),), "sigmoid")


def _stable_sigmoid(z: np.ndarray) -> np.ndarray:
    """1 / (1 + e^-z) for z >= 0, e^z / (1 + e^z) otherwise: e = e^-|z| never overflows."""
    e = np.exp(-np.abs(z))
    return (np.where(z >= 0, 1, e) / (1 + e)).astype(z.dtype, copy=False)


def tanh(x) -> Tensor:
    """y = tanh x;  dy/dx = 1 - y^2."""
    x = as_tensor(x)
    y = np.tanh(x.data)
    return Tensor.from_op(y, (x,), lambda g: (g * (1 - y * y),), "tanh")


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
    a, b = broadcast_pair(a, b, "where")
    y = np.where(cond, a.data, b.data)
    return Tensor.from_op(y, (a, b),
                          lambda g: (unbroadcast(np.where(cond, g, 0), a.shape),
                                     unbroadcast(np.where(cond, 0, g), b.shape)), "where")


def maximum(a, b) -> Tensor:
    """y = max(a, b);  the gradient goes to the larger (to a on ties)."""
    a, b = broadcast_pair(a, b, "maximum")
    return where(a.data >= b.data, a, b)


def minimum(a, b) -> Tensor:
    """y = min(a, b);  the gradient goes to the smaller (to a on ties)."""
    a, b = broadcast_pair(a, b, "minimum")
    return where(a.data <= b.data, a, b)
