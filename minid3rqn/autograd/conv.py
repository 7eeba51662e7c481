"""Convolution and upsampling on NCHW images.

Names and argument order follow ``torch.nn.functional``: ``conv2d(x, weight, bias,
stride, padding)`` and ``upsample(x, scale_factor, mode)`` (``F.interpolate``).

Convolution as one matrix product (im2col)
------------------------------------------
With ``x`` zero-padded to ``xp``, a convolution (a cross-correlation, as in PyTorch) is

    y[n, o, u, v] = b[o] + sum_{c, i, j} w[o, c, i, j] xp[n, c, s u + i, s v + j]

Lay every receptive field out as one row of a matrix ``cols`` (N*OH*OW rows, one per
output pixel; KH*KW*C columns, one per weight) and the whole layer is one GEMM,
``Y = cols @ W^T`` with ``W`` the weight reshaped to (C_out, KH*KW*C). ``cols`` is a
strided *view* of ``xp`` (no arithmetic, ``as_strided``) copied once into a dense
matrix. The gradients are two more GEMMs::

    dL/dW    = G^T @ cols                 (G = dL/dY, one row per output pixel)
    dL/dcols = G @ W        and dL/dxp[window of a row] += that row  (col2im)

col2im is the adjoint of im2col: every window adds its row back to the pixels it
read. Those sums are themselves a convolution, the *transposed convolution* of ``G``
(``kernels.transposed_conv``): a stride-1 correlation of the zero-padded ``G`` with the
flipped kernel, i.e. one more im2col + GEMM. With stride s the input splits into s x s
interleaved phases, each a stride-1 correlation with the kernel taps ``w[..., a::s,
b::s]`` (the "sub-pixel" decomposition).

How it is made fast (cache-sized blocks of cols, channels-last memory, the weight
matrix cached until the weight changes, buffers reused under ``no_grad``) is the
business of ``kernels.py``; the ops below read as the math.
"""
from __future__ import annotations

import numpy as np

from . import kernels
from .engine import Tensor, float_tensor, is_grad_enabled

# -- argument checking ---------------------------------------------------------------


def _same_dtype(op: str, **tensors: Tensor) -> None:
    if len({t.dtype for t in tensors.values() if t is not None}) == 1:
        return
    dtypes = {name: t.dtype for name, t in tensors.items() if t is not None}
    if len(set(dtypes.values())) > 1:
        listed = ", ".join(f"{name} is {d}" for name, d in dtypes.items())
        raise TypeError(f"{op}: inputs mix dtypes ({listed}); convert them to one dtype "
                        f"(float32 for training, float64 for gradient checks)")


def _image(x: Tensor, op: str) -> None:
    if x.ndim != 4:
        raise ValueError(f"{op}: x must be a 4-D NCHW tensor (N, C, H, W); got shape "
                         f"{x.shape}")


def _int_pair(value, name: str, op: str, minimum: int) -> tuple[int, int]:
    """An int or a pair of ints, each >= minimum, as a pair."""
    if type(value) is tuple and len(value) == 2 and type(value[0]) is type(value[1]) is int \
            and min(value) >= minimum:
        return value
    pair = value if isinstance(value, (tuple, list)) else (value, value)
    ok = len(pair) == 2 and all(isinstance(v, (int, np.integer)) and
                                not isinstance(v, bool) for v in pair)
    if not ok or min(pair) < minimum:
        kind = "positive" if minimum == 1 else "non-negative"
        raise ValueError(f"{op}: {name} must be a {kind} int or a pair of {kind} ints "
                         f"(h, w); got {value!r}")
    return int(pair[0]), int(pair[1])


def _out_size(op: str, x_shape, kernel, stride, padding) -> tuple[int, int]:
    """(OH, OW) = floor((H + 2 p - K) / s) + 1 per axis; an error if K > H + 2 p."""
    (H, W), (KH, KW), (ph, pw) = x_shape[2:], kernel, padding
    if KH > H + 2 * ph or KW > W + 2 * pw:
        raise ValueError(f"{op}: kernel {KH}x{KW} is larger than the padded input "
                         f"{H + 2 * ph}x{W + 2 * pw} (x {tuple(x_shape)} with padding "
                         f"{padding})")
    return (H + 2 * ph - KH) // stride[0] + 1, (W + 2 * pw - KW) // stride[1] + 1


def _check_conv_args(op, x, weight, bias):
    _image(x, op)
    if weight.ndim != 4:
        raise ValueError(f"{op}: weight must be 4-D (C_out, C_in, KH, KW); got shape "
                         f"{weight.shape}")
    if x.shape[1] != weight.shape[1]:
        raise ValueError(f"{op}: x has {x.shape[1]} channels but weight {weight.shape} "
                         f"expects C_in = {weight.shape[1]} (axis 1)")
    if bias is not None and bias.shape != (weight.shape[0],):
        raise ValueError(f"{op}: bias must have shape (C_out,) = ({weight.shape[0]},); "
                         f"got {bias.shape}")
    _same_dtype(op, x=x, weight=weight, bias=bias)


# -- convolution ------------------------------------------------------------------------


def conv2d(x, weight, bias=None, stride=1, padding=0) -> Tensor:
    """2-D convolution (cross-correlation, as ``torch.nn.functional.conv2d``).

    Args:
        x: (N, C_in, H, W).   weight: (C_out, C_in, KH, KW).   bias: (C_out,) or None.
        stride, padding: an int or an (h, w) pair; zero padding on both sides.

    Returns:
        (N, C_out, OH, OW) with OH = floor((H + 2 p_h - KH) / s_h) + 1 (same for W).

    Math (module docstring): y = b + cols @ W^T with cols the im2col matrix;
    dL/dW = G^T cols, dL/db = sum of G over pixels, dL/dx = the transposed convolution
    of G (``kernels.transposed_conv``).
    """
    op = "conv2d"
    x, weight = float_tensor(x, "x", op), float_tensor(weight, "weight", op)
    bias = None if bias is None else float_tensor(bias, "bias", op)
    _check_conv_args(op, x, weight, bias)
    stride = _int_pair(stride, "stride", op, 1)
    padding = _int_pair(padding, "padding", op, 0)
    N, C, H, W = x.shape
    O, _, KH, KW = weight.shape
    OH, OW = _out_size(op, x.shape, (KH, KW), stride, padding)
    (ph, pw) = padding

    graph = is_grad_enabled() and (x.requires_grad or weight.requires_grad or
                                   (bias is not None and bias.requires_grad))
    # y = cols @ W^T, channels-last (N, OH, OW, O); xp the zero-padded input
    y, xp = kernels.conv2d_forward(x.data, weight, (KH, KW), stride, padding, (OH, OW),
                                   keep_input=graph)
    if bias is not None:
        kernels.add_channels(y, bias.data)                       # y += b
    out = kernels.nchw_view(y)
    if not graph:
        return Tensor(out)

    def vjp(g):
        g = kernels.nhwc(g)                                      # (N, OH, OW, O)
        dx = dw = db = None
        if x.requires_grad:                                      # the transposed conv
            dx = kernels.nchw_view(kernels.transposed_conv(g, weight.data, stride,
                                                           (ph, pw), (H, W)))
        if weight.requires_grad:                                 # (cols^T G)^T = G^T cols
            dw = kernels.conv_weight_grad(xp, (KH, KW), stride, g).T
            dw = np.ascontiguousarray(dw.reshape(O, KH, KW, C).transpose(0, 3, 1, 2))
        if bias is not None and bias.requires_grad:         # sum over pixels, as a GEMV
            pixels = g.reshape(-1, O)                            # (6x faster than .sum)
            db = np.ones(len(pixels), dtype=g.dtype) @ pixels
        return dx, dw, db

    parents = (x, weight) if bias is None else (x, weight, bias)
    return Tensor.from_op(out, parents, vjp, op)


# -- upsampling -------------------------------------------------------------------------


def upsample(x, scale_factor=2, mode: str = "nearest") -> Tensor:
    """Enlarge an NCHW image by an integer factor (``F.interpolate``).

    Args:
        x: (N, C, H, W).   scale_factor: a positive int or an (h, w) pair.
        mode: "nearest" or "bilinear" (``align_corners=False``).

    Returns:
        (N, C, s_h H, s_w W).

    nearest:  y[.., s i + a, s j + b] = x[.., i, j];  dL/dx[i, j] = the sum of G over
              its s x s block (s + s strided slice adds).
    bilinear: separable; along each axis output pixel k reads the input at
              t = (k + 1/2) / s - 1/2 (pixel centres line up, PyTorch's
              ``align_corners=False``), clamped to [0, L - 1], and mixes the two
              neighbours floor(t), floor(t) + 1 with weights 1 - frac(t), frac(t).
              For output k = s i + a that is x[i] and x[i -+ 1] with fixed weights per
              phase a; the gradient sends G back along the same two weights.
    """
    op = "upsample"
    x = float_tensor(x, "x", op)
    _image(x, op)
    sh, sw = _int_pair(scale_factor, "scale_factor", op, 1)
    N, C, H, W = x.shape
    if mode == "nearest":
        y = kernels.repeat_nearest(x.data, sh, sw, remember=not is_grad_enabled())

        def vjp(g):
            return (_sum_phases(_sum_phases(g, sw, 3), sh, 2),)
    elif mode == "bilinear":
        y = _lerp_up(_lerp_up(x.data, sh, 2), sw, 3)

        def vjp(g):
            return (_lerp_up_adjoint(_lerp_up_adjoint(g, sw, 3), sh, 2),)
    else:
        raise ValueError(f"{op}: mode must be 'nearest' or 'bilinear'; got {mode!r}")
    return Tensor.from_op(y, (x,), vjp, f"upsample_{mode}")


def _sum_phases(g: np.ndarray, s: int, axis: int) -> np.ndarray:
    """The adjoint of ``np.repeat(x, s, axis)``: out[i] = sum_a g[s i + a]. (Strided
    slice adds: much faster in NumPy than ``g.reshape(..., s).sum(-1)``.)"""
    if s == 1:
        return g
    out = g[_along(axis, slice(0, None, s))].copy()
    for a in range(1, s):
        out += g[_along(axis, slice(a, None, s))]
    return out


def _lerp_phases(s: int):
    """Per output phase a: (offset of the second neighbour, its weight) in -1/0/+1."""
    for a in range(s):
        d = (a + 0.5) / s - 0.5                 # t - i for output k = s i + a
        yield a, (-1 if d < 0 else 1), abs(d)


def _along(axis: int, sl) -> tuple:
    return (slice(None),) * axis + (sl,)


def _lerp_up(x: np.ndarray, s: int, axis: int) -> np.ndarray:
    """Linear upsampling by ``s`` along ``axis`` (edge-clamped, align_corners=False)."""
    if s == 1:
        return x
    L = x.shape[axis]
    edge = np.concatenate([x[_along(axis, slice(0, 1))], x,
                           x[_along(axis, slice(L - 1, L))]], axis=axis)  # x[-1], x[L]
    shape = list(x.shape)
    shape[axis] = L * s
    y = np.empty(shape, dtype=x.dtype)
    centre = edge[_along(axis, slice(1, L + 1))]
    towards = {off: edge[_along(axis, slice(1 + off, L + 1 + off))] - centre
               for off in (-1, 1)}                  # x[i -+ 1] - x[i]
    for a, off, wt in _lerp_phases(s):              # y = x[i] + wt (x[i + off] - x[i])
        ya = y[_along(axis, slice(a, None, s))]
        np.multiply(towards[off], wt, out=ya)
        ya += centre
    return y


def _lerp_up_adjoint(g: np.ndarray, s: int, axis: int) -> np.ndarray:
    """The transpose of ``_lerp_up``: each output's gradient goes back to its two
    neighbours with the same weights; the clamped neighbours fold onto the edges."""
    if s == 1:
        return g
    L = g.shape[axis] // s
    shape = list(g.shape)
    shape[axis] = L + 2
    edge = np.zeros(shape, dtype=g.dtype)
    centre = edge[_along(axis, slice(1, L + 1))]
    for a, off, wt in _lerp_phases(s):
        ga = g[_along(axis, slice(a, None, s))]
        part = ga * wt
        centre += ga                                # (1 - wt) ga to x[i] ...
        centre -= part
        edge[_along(axis, slice(1 + off, L + 1 + off))] += part   # ... wt ga to x[i+off]
    dx = edge[_along(axis, slice(1, L + 1))].copy()
    dx[_along(axis, slice(0, 1))] += edge[_along(axis, slice(0, 1))]
    dx[_along(axis, slice(L - 1, L))] += edge[_along(axis, slice(L + 1, L + 2))]
    return dx
