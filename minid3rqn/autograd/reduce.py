"""Reductions: sum, mean, max, log_softmax over axes, with their vector-Jacobian products.

A reduction removes axes; its gradient puts them back (``keepdims`` shape) and
broadcasts ``g`` over them, because every reduced entry influenced the result.
"""
from __future__ import annotations

import builtins

import numpy as np

from .engine import Tensor, as_tensor


def _axes(axis, ndim: int, op: str) -> tuple[int, ...]:
    if axis is None:
        return tuple(range(ndim))
    axes = (axis,) if isinstance(axis, (int, np.integer)) else tuple(axis)
    out = []
    for a in axes:
        if not -ndim <= a < builtins.max(ndim, 1):
            raise ValueError(f"{op}: axis {a} is out of range for a tensor with "
                             f"{ndim} dimensions")
        out.append(a % builtins.max(ndim, 1))
    return tuple(sorted(set(out)))


def _regrow(g: np.ndarray, axes: tuple[int, ...], keepdims: bool) -> np.ndarray:
    """g with the reduced axes restored as length-1 axes (ready to broadcast)."""
    return g if keepdims else np.expand_dims(g, axes)


def sum(x, axis=None, keepdims: bool = False) -> Tensor:
    """y = sum_i x_i over ``axis``;  dy/dx_i = 1."""
    x = as_tensor(x)
    axes = _axes(axis, x.ndim, "sum")
    y = np.sum(x.data, axis=axes, keepdims=keepdims)
    return Tensor.from_op(np.asarray(y), (x,),
                          lambda g: (np.broadcast_to(_regrow(g, axes, keepdims),
                                                     x.shape).copy(),), "sum")


def mean(x, axis=None, keepdims: bool = False) -> Tensor:
    """y = (1/n) sum_i x_i over ``axis``;  dy/dx_i = 1/n."""
    x = as_tensor(x)
    axes = _axes(axis, x.ndim, "mean")
    n = int(np.prod([x.shape[a] for a in axes])) if axes else 1
    y = np.mean(x.data, axis=axes, keepdims=keepdims)
    return Tensor.from_op(np.asarray(y, dtype=x.dtype), (x,),
                          lambda g: (np.broadcast_to(_regrow(g, axes, keepdims) / n,
                                                     x.shape).astype(x.dtype),), "mean")


def max(x, axis=None, keepdims: bool = False) -> Tensor:
    """y = max_i x_i over ``axis``;  dy/dx_i = 1 at the maximum, else 0.

    On ties the gradient is shared equally among the tied entries (a subgradient).
    """
    x = as_tensor(x)
    axes = _axes(axis, x.ndim, "max")
    y_keep = np.max(x.data, axis=axes, keepdims=True)
    y = y_keep if keepdims else np.squeeze(y_keep, axis=axes)

    def vjp(g):
        hit = x.data == y_keep
        share = hit / np.sum(hit, axis=axes, keepdims=True)
        return (_regrow(g, axes, keepdims) * share.astype(x.dtype),)

    return Tensor.from_op(np.asarray(y), (x,), vjp, "max")


def log_softmax(x, axis: int = -1) -> Tensor:
    """y_i = x_i - log sum_j exp(x_j) over ``axis`` (one axis; the shape is kept).

    Computed as (x_i - m) - log sum_j exp(x_j - m) with m = max_j x_j, so no exp
    overflows. With p = softmax(x) = exp(y), dy_i/dx_k = [i = k] - p_k, hence

        dL/dx_k = g_k - p_k * sum_i g_i.
    """
    x = as_tensor(x)
    if isinstance(axis, bool) or not isinstance(axis, (int, np.integer)):
        raise TypeError(f"log_softmax: axis must be one int; got {axis!r}")
    (ax,) = _axes(axis, x.ndim, "log_softmax")
    if x.ndim == 0:
        raise ValueError("log_softmax: needs at least one axis; got a 0-d tensor")
    shifted = x.data - np.max(x.data, axis=ax, keepdims=True)
    y = shifted - np.log(np.sum(np.exp(shifted), axis=ax, keepdims=True))

    def vjp(g):
        return (g - np.exp(y) * np.sum(g, axis=ax, keepdims=True),)

    return Tensor.from_op(y.astype(x.dtype, copy=False), (x,), vjp, "log_softmax")


__all__ = ["sum", "mean", "max", "log_softmax"]
