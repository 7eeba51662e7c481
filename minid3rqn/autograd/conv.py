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
(``_transposed_conv``): a stride-1 correlation of the zero-padded ``G`` with the
flipped kernel, i.e. one more im2col + GEMM. With stride s the input splits into s x s
interleaved phases, each a stride-1 correlation with the kernel taps ``w[..., a::s,
b::s]`` (the "sub-pixel" decomposition).

Speed (benchmarks/bench_autograd.py): cols is KH*KW times the size of the image, so it
is built and consumed in cache-sized blocks (``_BLOCK_BYTES``) and rebuilt by the
backward pass, never stored whole; im2col reads the input channels-last (NHWC); outputs
and gradients are NCHW-*shaped* views of channels-last memory, which the next
convolution reads without a transposing copy.
"""
from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import as_strided

from .engine import Tensor, float_tensor

# -- argument checking ---------------------------------------------------------------


def _same_dtype(op: str, **tensors: Tensor) -> None:
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


# -- the machinery: channels-last im2col and the transposed convolution ---------------


def _pad_nhwc(x: np.ndarray, ph: int, pw: int) -> np.ndarray:
    """NCHW ``x`` -> channels-last (N, H + 2 ph, W + 2 pw, C), zeros around. One copy,
    which also does the transposition."""
    N, C, H, W = x.shape
    out = np.zeros((N, H + 2 * ph, W + 2 * pw, C), dtype=x.dtype)
    out[:, ph:ph + H, pw:pw + W] = x.transpose(0, 2, 3, 1)
    return out


# cols is built and consumed in blocks of about this many bytes, so that each block
# stays in the CPU's L2 cache between the copy that writes it and the GEMM that reads it.
_BLOCK_BYTES = 512 * 1024
# window rows (KW*C values) shorter than this are copied tap-major (``_im2col_views``)
_SHORT_RUN = 12


def _windows(xp: np.ndarray, kernel, stride, out_hw) -> np.ndarray:
    """Channels-last ``xp`` (N, Hp, Wp, C) -> the read-only view (N, OH, OW, KH, KW, C)
    of all receptive fields: ``[n, u, v]`` is ``xp[n, s u : s u + KH, s v : s v + KW]``.
    Reshaped to (N*OH*OW, KH*KW*C) (a copy) it is the im2col matrix ``cols``."""
    N, _, _, C = xp.shape
    (KH, KW), (sh, sw), (OH, OW) = kernel, stride, out_hw
    bn, bh, bw, bc = xp.strides
    return as_strided(xp, (N, OH, OW, KH, KW, C), (bn, sh * bh, sw * bw, bh, bw, bc),
                      writeable=False)


def _blocks(windows: np.ndarray):
    """Split the output pixels into blocks of whole images or of image rows whose
    cols rows fill about ``_BLOCK_BYTES``; yields ``(block of windows, index)``."""
    N, OH, OW = windows.shape[:3]
    row_bytes = OW * windows[0, 0, 0].size * windows.itemsize
    if OH * row_bytes <= _BLOCK_BYTES:                      # several whole images
        step = max(1, _BLOCK_BYTES // (OH * row_bytes))
        for n in range(0, N, step):
            yield windows[n:n + step], np.s_[n:n + step]
    else:                                                   # rows of one image
        step = max(1, _BLOCK_BYTES // row_bytes)
        for n in range(N):
            for r in range(0, OH, step):
                yield windows[n:n + 1, r:r + step], np.s_[n:n + 1, r:r + step]


def _im2col_views(block: np.ndarray, buf: np.ndarray):
    """How a block of windows (n, r, OW, KH, KW, C) becomes the (n*r*OW, KH*KW*C) cols
    matrix in ``buf``: ``(dst, src, cols)``, where ``np.copyto(dst, src)`` fills
    ``cols`` (all three are views; nothing is copied here).

    The copy's cost is per contiguous run, so the memory order follows the longer run:
    pixel-major (a window row of KW*C floats) or, with few channels, tap-major (a run of
    OW output pixels per kernel tap and channel; cols is then the transpose of a
    (KH*KW*C, m) matrix).
    """
    n, r, OW, KH, KW, C = block.shape
    m, K = n * r * OW, KH * KW * C
    if KW * C >= _SHORT_RUN:
        cols = buf[:m * K].reshape(m, K)
        return cols.reshape(block.shape), block, cols
    cols_t = buf[:m * K].reshape(K, m)
    return (cols_t.reshape(KH, KW, C, n, r, OW), block.transpose(3, 4, 5, 0, 1, 2),
            cols_t.T)


def conv2d_nhwc_plan(xp: np.ndarray, kernel, stride, out_hw, out: np.ndarray,
                     work: np.ndarray | None = None) -> list:
    """The schedule of ``conv2d_nhwc`` without running it: for each cache-sized block
    of output pixels, ``(dst, src, cols, y)`` (views into ``work``, ``xp`` and ``out``)
    meaning ``np.copyto(dst, src); np.matmul(cols, wmat_t, out=y)``.

    A caller that convolves the same buffers again and again (the inference paths)
    builds it once and runs it with ``run_conv_plan``, skipping the strided views.
    ``work``: a 1-D scratch of at least ``im2col_work_size`` elements (None: a new one).
    """
    windows = _windows(xp, kernel, stride, out_hw)
    O = out.shape[3]
    plan = []
    for block, index in _blocks(windows):
        if work is None:                      # the first block is the largest
            work = np.empty(block.size, dtype=xp.dtype)
        dst, src, cols = _im2col_views(block, work)
        plan.append((dst, src, cols, out[index].reshape(len(cols), O)))  # a view
    return plan


def run_conv_plan(plan: list, wmat_t: np.ndarray) -> None:
    """Run a ``conv2d_nhwc_plan``: im2col one block, one GEMM, next block."""
    for dst, src, cols, y in plan:
        np.copyto(dst, src)
        np.matmul(cols, wmat_t, out=y)


def conv2d_nhwc(xp: np.ndarray, kernel, stride, out_hw, wmat_t: np.ndarray,
                out: np.ndarray | None = None, work: np.ndarray | None = None
                ) -> np.ndarray:
    """Channels-last convolution without bias: ``y = cols @ wmat_t``, (N, OH, OW, O).

    The convolution arithmetic in one place: ``conv2d``'s forward, its input gradient
    (``_transposed_conv``) and the graph-free inference path (``nets.fast``) run it.
    ``xp`` is the zero-padded input, channels-last (N, Hp, Wp, C); ``wmat_t`` the weight
    as a (KH*KW*C, O) matrix (rows ordered like a cols row). ``out`` (C-contiguous
    (N, OH, OW, O)) and ``work`` (1-D scratch of ``im2col_work_size`` elements) let a
    caller reuse its memory.
    """
    N, (OH, OW), O = xp.shape[0], out_hw, wmat_t.shape[1]
    y = np.empty((N, OH, OW, O), dtype=xp.dtype) if out is None else out
    run_conv_plan(conv2d_nhwc_plan(xp, kernel, stride, out_hw, y, work), wmat_t)
    return y


def im2col_work_size(xp: np.ndarray, kernel, stride, out_hw) -> int:
    """Elements of the scratch ``work`` that ``conv2d_nhwc`` needs for this input: the
    size of its first (largest) block of cols."""
    block, _ = next(_blocks(_windows(xp, kernel, stride, out_hw)))
    return block.size


def _conv_weight_grad(xp: np.ndarray, kernel, stride, g: np.ndarray) -> np.ndarray:
    """``cols^T @ G`` = dL/dW as a (KH*KW*C, O) matrix, for ``g`` (N, OH, OW, O)
    channels-last; cols is rebuilt block by block from ``xp`` (cheaper than keeping
    it: see ``_BLOCK_BYTES``)."""
    windows = _windows(xp, kernel, stride, g.shape[1:3])
    K, O = windows[0, 0, 0].size, g.shape[3]
    total = np.zeros((K, O), dtype=xp.dtype)
    buf = None
    for block, index in _blocks(windows):
        if buf is None:
            buf = np.empty(block.size, dtype=xp.dtype)
        dst, src, cols = _im2col_views(block, buf)
        np.copyto(dst, src)
        total += cols.T @ g[index].reshape(len(cols), O)
    return total


def _transposed_conv(g: np.ndarray, weight: np.ndarray, stride, origin, out_hw
                     ) -> np.ndarray:
    """The adjoint of a convolution's input, channels-last, on a window of its input.

    ``g`` (N, OH, OW, O) channels-last, ``weight`` (O, C, KH, KW). Returns ``z`` (N,
    Hz, Wz, C) with, for padded-input pixel (Y, X) = (y0 + r, x0 + q),

        z[n, r, q, c] = sum_{u, i: s u + i = Y} sum_{v, j: s v + j = X}
                        sum_o g[n, u, v, o] w[o, c, i, j]

    (col2im of ``g @ W``). Rows with Y = s Y' + a (phase a) only meet the taps
    i = a + s i', at u = Y' - i': a stride-1 correlation of ``g`` with the flipped
    taps ``w[:, :, a::s]``. Per phase (a, b): pad ``g``, im2col, one GEMM, and write
    the result to ``z[:, a'::s, b'::s]``.
    """
    N, OH, OW, O = g.shape
    _, C, KH, KW = weight.shape
    (sh, sw), (y0, x0), (Hz, Wz) = stride, origin, out_hw
    z = None if sh == sw == 1 else np.empty((N, Hz, Wz, C), dtype=g.dtype)
    for a in range(sh):
        r0 = (a - y0) % sh                    # first row of z in phase a
        lo_y = (y0 + r0 - a) // sh            # its Y'
        ny = len(range(r0, Hz, sh))           # rows of z in phase a
        for b in range(sw):
            q0 = (b - x0) % sw
            lo_x = (x0 + q0 - b) // sw
            nx = len(range(q0, Wz, sw))
            if ny == 0 or nx == 0:
                continue
            taps = weight[:, :, a::sh, b::sw]             # (O, C, ka, kb)
            ka, kb = taps.shape[2:]
            if ka == 0 or kb == 0:                        # stride > kernel: no tap
                z[:, r0::sh, q0::sw] = 0
                continue
            # gp[t] = g[lo_y - ka + 1 + t] (zero outside 0..OH-1); window t..t+ka-1
            gp = np.zeros((N, ny + ka - 1, nx + kb - 1, O), dtype=g.dtype)
            u0, v0 = lo_y - ka + 1, lo_x - kb + 1
            us, ue = max(u0, 0), min(u0 + ny + ka - 1, OH)
            vs, ve = max(v0, 0), min(v0 + nx + kb - 1, OW)
            if us < ue and vs < ve:
                gp[:, us - u0:ue - u0, vs - v0:ve - v0] = g[:, us:ue, vs:ve]
            flipped = taps[:, :, ::-1, ::-1].transpose(2, 3, 0, 1).reshape(ka * kb * O, C)
            part = conv2d_nhwc(gp, (ka, kb), (1, 1), (ny, nx), flipped)
            if z is None:                                 # stride 1: a single phase
                return part
            z[:, r0::sh, q0::sw] = part
    return z


def _nhwc(g: np.ndarray) -> np.ndarray:
    """NCHW-shaped ``g`` as a C-contiguous channels-last array (free if it already is)."""
    return np.ascontiguousarray(g.transpose(0, 2, 3, 1))


def _nchw_view(y: np.ndarray) -> np.ndarray:
    return y.transpose(0, 3, 1, 2)


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
    of G (``_transposed_conv``).
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

    xp = _pad_nhwc(x.data, ph, pw)                     # (N, Hp, Wp, C)
    wmat = weight.data.transpose(0, 2, 3, 1).reshape(O, KH * KW * C)
    y = conv2d_nhwc(xp, (KH, KW), stride, (OH, OW), wmat.T)     # cols @ W^T
    if bias is not None:
        y += bias.data
    out = _nchw_view(y)

    def vjp(g):
        g = _nhwc(g)                                             # (N, OH, OW, O)
        dx = dw = db = None
        if x.requires_grad:
            dx = _nchw_view(_transposed_conv(g, weight.data, stride, (ph, pw), (H, W)))
        if weight.requires_grad:                                 # (cols^T G)^T = G^T cols
            dw = _conv_weight_grad(xp, (KH, KW), stride, g).T
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
        y = np.repeat(np.repeat(x.data, sh, axis=2), sw, axis=3)

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
