"""Ops that move entries without computing with them: concat, stack, pad, crop, flatten.

Their gradients move ``g`` back the same way: split along the concatenated axis, take
the slice of each stacked input, cut (or fold back) the padding, write the cropped
part into zeros. reshape, transpose and
getitem sit in engine.py, beside the Tensor whose methods call them.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from . import kernels
from .engine import Tensor, as_tensor, check_same_dtype, reshape


def concat(tensors: Sequence[Tensor], axis: int = 0) -> Tensor:
    """y = [x_1, x_2, ...] joined along ``axis``;  dL/dx_i = the slice of g for x_i."""
    tensors = [as_tensor(t) for t in tensors]
    if not tensors:
        raise ValueError("concat: needs at least one tensor")
    check_same_dtype(tensors, "concat")
    try:
        y = kernels.concatenate([t.data for t in tensors], axis=axis)
    except ValueError as e:
        raise ValueError(f"concat: shapes {[t.shape for t in tensors]} do not join along "
                         f"axis {axis}: {e}") from None
    bounds = np.cumsum([t.shape[axis] for t in tensors])[:-1]
    return Tensor.from_op(y, tensors, lambda g: tuple(np.split(g, bounds, axis=axis)),
                          "concat")


def stack(tensors: Sequence[Tensor], axis: int = 0) -> Tensor:
    """y = x_1, x_2, ... stacked on a new ``axis``;  dL/dx_i = g taken at i on that axis."""
    tensors = [as_tensor(t) for t in tensors]
    if not tensors:
        raise ValueError("stack: needs at least one tensor")
    check_same_dtype(tensors, "stack")
    shapes = {t.shape for t in tensors}
    if len(shapes) > 1:
        raise ValueError(f"stack: all tensors must have one shape; got {sorted(shapes)}")
    y = np.stack([t.data for t in tensors], axis=axis)
    n = len(tensors)
    return Tensor.from_op(y, tensors,
                          lambda g: tuple(np.take(g, i, axis=axis) for i in range(n)),
                          "stack")


def pad(x, pad_width, mode: str = "constant", value: float = 0.0) -> Tensor:
    """y = x padded (NumPy's ``pad_width``: a (before, after) pair per axis).

    Modes: "constant" (with ``value``) and "edge" (replicate the border).
    dL/dx: for constant, the interior of g; for edge, the interior plus the border
    copies folded back onto the edge entries they came from.
    """
    x = as_tensor(x)
    pw = tuple((int(a), int(b)) for a, b in np.broadcast_to(np.asarray(pad_width), (x.ndim, 2)))
    if any(a < 0 or b < 0 for a, b in pw):
        raise ValueError(f"pad: pad_width must be non-negative; got {pw}")
    if mode == "constant":
        y = np.pad(x.data, pw, mode="constant", constant_values=value)
    elif mode == "edge":
        y = np.pad(x.data, pw, mode="edge")
    else:
        raise ValueError(f"pad: mode must be 'constant' or 'edge'; got {mode!r}")

    def vjp(g):
        if mode == "edge":  # fold each padded band onto the edge slice, axis by axis
            for axis, (before, after) in enumerate(pw):
                n = g.shape[axis]
                if before:
                    head = np.take(g, range(before), axis=axis).sum(axis=axis, keepdims=True)
                    g = np.take(g, range(before, n), axis=axis).copy()
                    _add_slice(g, axis, 0, head)
                    n -= before
                if after:
                    tail = np.take(g, range(n - after, n), axis=axis).sum(axis=axis, keepdims=True)
                    g = np.take(g, range(0, n - after), axis=axis).copy()
                    _add_slice(g, axis, -1, tail)
            return (g,)
        inner = tuple(slice(a, g.shape[i] - b) for i, (a, b) in enumerate(pw))
        return (g[inner],)

    return Tensor.from_op(y, (x,), vjp, "pad")


def _add_slice(arr: np.ndarray, axis: int, i: int, value: np.ndarray) -> None:
    index = [slice(None)] * arr.ndim
    index[axis] = slice(i, i + 1) if i >= 0 else slice(i, None)
    arr[tuple(index)] += value


def crop(x, index) -> Tensor:
    """y = x[index] for basic slices and ints only;  dL/dx = g written into zeros.

    A faster twin of ``getitem`` for the many shifted slices of the losses and the
    LSTM's outputs: basic slices read no entry twice, so plain assignment is exact.
    """
    x = as_tensor(x)

    def vjp(g):
        gx = np.zeros_like(x.data)
        gx[index] = g
        return (gx,)

    return Tensor.from_op(np.ascontiguousarray(x.data[index]), (x,), vjp, "crop")


def flatten(x, start_dim: int = 1) -> Tensor:
    """y = x with the axes from ``start_dim`` on merged into one."""
    x = as_tensor(x)
    return reshape(x, x.shape[:start_dim] + (-1,))
