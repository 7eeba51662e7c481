"""log_softmax, the reduction the losses need beyond sum, mean and max.

sum, mean and max sit in engine.py, beside the Tensor whose methods call them.
"""
from __future__ import annotations

import numpy as np

from .engine import Tensor, as_tensor, reduction_axes


def log_softmax(x, axis: int = -1) -> Tensor:
    """y_i = x_i - log sum_j exp(x_j) over ``axis`` (one axis; the shape is kept).

    Computed as (x_i - m) - log sum_j exp(x_j - m) with m = max_j x_j, so no exp
    overflows. With p = softmax(x) = exp(y), dy_i/dx_k = [i = k] - p_k, hence

        dL/dx_k = g_k - p_k * sum_i g_i.
    """
    x = as_tensor(x)
    if isinstance(axis, bool) or not isinstance(axis, (int, np.integer)):
        raise TypeError(f"log_softmax: axis must be one int; got {axis!r}")
    (ax,) = reduction_axes(axis, x.ndim, "log_softmax")
    if x.ndim == 0:
        raise ValueError("log_softmax: needs at least one axis; got a 0-d tensor")
    shifted = x.data - np.max(x.data, axis=ax, keepdims=True)
    y = shifted - np.log(np.sum(np.exp(shifted), axis=ax, keepdims=True))

    def vjp(g):
        return (g - np.exp(y) * np.sum(g, axis=ax, keepdims=True),)

    return Tensor.from_op(y.astype(x.dtype, copy=False), (x,), vjp, "log_softmax")
