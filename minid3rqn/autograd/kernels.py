"""The kernels behind the ops: memory layouts, cache blocking, plans, reused buffers.

``conv.py`` states the convolution and its gradient, ``lstm.py`` the LSTM; this module
makes them fast, as minitorch keeps ``fast_ops`` apart from its tensor math. What is
computed stays the same; only where it is stored and in what order the work is done
change (and, under ``no_grad``, the two schedules at the end).

Layouts. Images are NCHW-*shaped* for the ops, but a convolution's output lives in
channels-last (N, H, W, C) memory, which is what the next im2col reads and what a GEMM
writes row by row; ``nchw_view`` and ``nhwc`` move between the two without copying
when they can. Elementwise ops, upsampling and concatenation keep that layout
(``empty_like_layout``), so an activation never goes through a transposing copy.

Blocking. ``cols`` (the im2col matrix) is KH*KW times the image; it is built and
consumed in blocks of about ``_BLOCK_BYTES``, so a block is still in the L2 cache when
the GEMM reads it (``_blocks``), and rebuilt by the backward pass, never stored whole.

Caches, valid until the weight changes (``_derived``: keyed by the weight Tensor, its
array and its ``version``, which the optimizer, ``load_state_dict`` and ``set_`` bump):

- ``weight_matrix``: a conv weight (O, C, KH, KW) as the (KH*KW*C, O) GEMM operand;
- ``times_transposed``: an LSTM weight's W^T laid out contiguously;
- ``_Plan``: for one input shape, the im2col schedule (strided views of a padded input
  buffer and of a scratch buffer) built once and replayed. Under ``no_grad`` the
  padded input and the scratch are reused call after call (nothing keeps them: the
  backward pass is the only reader that would); with the graph on, the padded input is
  fresh, because the backward pass reads it. Outputs are always fresh arrays. One
  cache per thread, the least recently used plan dropped past ``_MAX_PLANS``.

Two schedules differ in their arithmetic, under ``no_grad`` only (the same products
summed in another order: equal to float round-off, not to the bit), so that training,
with the graph on, sums as it always has and reruns to the bit:

- a layer with very few output channels (KH*KW*C_out <= C_in, stride 1: a disparity
  head) contracts the channels first, ``P[t] = xp @ w[:, :, t]`` for each kernel tap
  t, and sums the KH*KW shifted tap images, without the KH*KW-times-larger im2col;
- a 3x3 convolution (stride 1, padding 1) of an array ``upsample`` made by nearest x2
  upsampling (``remember_upsampled``; made read-only so that it stays one) runs as
  four 2x2 convolutions of the small image, one per output phase
  (``_phase_matrices``): 4/9 of the multiply-adds.
"""
from __future__ import annotations

import threading
import weakref
from collections import OrderedDict

import numpy as np
from numpy.lib.stride_tricks import as_strided

# cols is built and consumed in blocks of about this many bytes, so that each block
# stays in the CPU's L2 cache between the copy that writes it and the GEMM that reads it.
_BLOCK_BYTES = 512 * 1024
# window rows (KW*C values) shorter than this are copied tap-major (``_im2col_views``)
_SHORT_RUN = 12
# plans kept per thread (least recently used dropped first)
_MAX_PLANS = 64


# -- layouts ------------------------------------------------------------------------------
def nchw_view(y: np.ndarray) -> np.ndarray:
    """Channels-last (N, H, W, C) memory seen as an NCHW array (no copy)."""
    return y.transpose(0, 3, 1, 2)


def nhwc(g: np.ndarray) -> np.ndarray:
    """NCHW-shaped ``g`` as a C-contiguous channels-last array (free if it already is)."""
    return np.ascontiguousarray(g.transpose(0, 2, 3, 1))


def channels_last(x: np.ndarray) -> bool:
    """Whether the NCHW-shaped ``x`` is stored channels-last (C the fastest axis)."""
    return x.ndim == 4 and x.transpose(0, 2, 3, 1).flags.c_contiguous


def empty_like_layout(shape, like: np.ndarray, dtype=None) -> np.ndarray:
    """An uninitialised NCHW array of ``shape``, stored channels-last if ``like`` is."""
    dtype = like.dtype if dtype is None else dtype
    if len(shape) == 4 and channels_last(like):
        n, c, h, w = shape
        return nchw_view(np.empty((n, h, w, c), dtype))
    return np.empty(shape, dtype)


_ZEROS: dict = {}


def zeros_like_layout(x: np.ndarray) -> np.ndarray | float:
    """A read-only array of zeros with ``x``'s shape and memory layout (views of one
    shared buffer), for ``np.maximum(x, zeros)``: NumPy's SIMD min/max loops run on two
    arrays of one layout, not on an array and a scalar. ``0`` when ``x`` is neither
    C-contiguous nor channels-last, or small (where the scalar costs less than this)."""
    if x.size < 16384:
        return 0
    if x.flags.c_contiguous:
        order = None
    elif channels_last(x):
        order = (0, 2, 3, 1)
    else:
        return 0
    buf = _ZEROS.get(x.dtype)
    if buf is None or buf.size < x.size:
        buf = np.zeros(max(x.size, 1 << 16), x.dtype)
        buf.flags.writeable = False
        _ZEROS[x.dtype] = buf
    if order is None:
        return buf[:x.size].reshape(x.shape)
    n, c, h, w = x.shape
    return nchw_view(buf[:x.size].reshape(n, h, w, c))


def add_channels(y: np.ndarray, b: np.ndarray) -> None:
    """``y += b`` for a C-contiguous channels-last ``y`` (N, H, W, C) and ``b`` (C,):
    ``b`` repeated along an image row, so NumPy adds rows of W*C values instead of
    broadcasting over runs of C (7x faster for C = 4)."""
    N, H, W, C = y.shape
    if y.size < 4096:                        # small: repeating b costs more than it saves
        y += b
    else:
        y.reshape(N * H, W * C).__iadd__(np.tile(b, W))


def pad_nhwc(x: np.ndarray, ph: int, pw: int, out: np.ndarray | None = None) -> np.ndarray:
    """NCHW ``x`` -> channels-last (N, H + 2 ph, W + 2 pw, C), zeros around. One copy,
    which also does the transposition (a plain copy if ``x`` is stored channels-last).
    ``out``: a buffer of that shape whose border already holds zeros."""
    N, C, H, W = x.shape
    if out is None:
        out = np.zeros((N, H + 2 * ph, W + 2 * pw, C), dtype=x.dtype)
    out[:, ph:ph + H, pw:pw + W] = x.transpose(0, 2, 3, 1)
    return out


# -- what a kernel derives from a weight, cached per weight version ------------------------
_DERIVED: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_DERIVED_LOCK = threading.Lock()


def _derived(weight, name: str, make):
    """``make(weight.data)``, computed once and reused while ``weight.version`` and its
    array stay the same (one entry per ``name``; forgotten with the weight)."""
    data = weight.data
    entries = _DERIVED.get(weight)
    if entries is None:
        with _DERIVED_LOCK:
            entries = _DERIVED.setdefault(weight, {})
    entry = entries.get(name)
    if entry is not None and entry[0] is data and entry[1] == weight.version:
        return entry[2]
    value = make(data)
    entries[name] = (data, weight.version, value)         # one assignment: thread-safe
    return value


def _gemm_operand(w: np.ndarray) -> np.ndarray:
    """(O, C, KH, KW) -> the (KH*KW*C, O) matrix, as the transposed view of a
    C-contiguous (O, KH*KW*C) array (the operand every conv has always had: the same
    BLAS kernel, the same sums)."""
    O, C, KH, KW = w.shape
    return np.ascontiguousarray(w.transpose(0, 2, 3, 1)).reshape(O, KH * KW * C).T


def times_transposed(x: np.ndarray, weight) -> np.ndarray:
    """``x @ weight.data.T`` for a 2-D ``x`` (rows, in) and weight (out, in), with
    ``W^T`` laid out contiguously once per weight version. Below 3 rows OpenBLAS runs a
    matrix-vector product, as fast on the transposed view and summed in another order
    than on the copy: there the view is used, so a result never depends on the cache."""
    if len(x) < 3:
        return x @ weight.data.T
    return x @ _derived(weight, "T", lambda w: np.ascontiguousarray(w.T))


def weight_matrix(weight) -> np.ndarray:
    """A convolution weight Tensor (O, C, KH, KW) as the (KH*KW*C, O) operand of
    ``cols @ W^T`` (rows ordered like a cols row: tap-major, channel fastest), cached
    per weight version."""
    return _derived(weight, "gemm", _gemm_operand)


def _tap_matrix(weight) -> np.ndarray:
    """The weight as (KH*KW*O, C): row (i*KW + j)*O + o holds w[o, :, i, j] (the
    contract-first schedule's operand), cached per weight version."""
    def make(w):
        O, C, KH, KW = w.shape
        return np.ascontiguousarray(w.transpose(2, 3, 0, 1).reshape(KH * KW * O, C))
    return _derived(weight, "taps", make)


def _phase_matrices(weight) -> dict:
    """A 3x3 kernel read by a nearest-x2-upsampled image, as four 2x2 kernels of the
    small image, one per output phase (p, q): {(p, q): (4C, O) GEMM operand}.

    Output pixel (2a + p, 2b + q) of ``conv3x3(upsample2(x))`` (padding 1) reads
    upsampled rows 2a + p - 1 .. 2a + p + 1, i.e. small rows (a - 1, a, a) for p = 0 and
    (a, a, a + 1) for p = 1 (the zero padding agrees), so taps reading one small row
    add up: rows (a - 1, a) with weights (w0, w1 + w2) for p = 0, rows (a, a + 1) with
    (w0 + w1, w2) for p = 1; columns alike. 4 x 4 = 16 multiply-adds per small pixel
    and channel pair instead of 4 x 9 = 36."""
    def make(w):
        rows = {0: lambda v: np.stack([v[:, :, 0], v[:, :, 1] + v[:, :, 2]], axis=2),
                1: lambda v: np.stack([v[:, :, 0] + v[:, :, 1], v[:, :, 2]], axis=2)}
        cols = {0: lambda v: np.stack([v[..., 0], v[..., 1] + v[..., 2]], axis=3),
                1: lambda v: np.stack([v[..., 0] + v[..., 1], v[..., 2]], axis=3)}
        return {(p, q): _gemm_operand(cols[q](rows[p](w))) for p in (0, 1) for q in (0, 1)}
    return _derived(weight, "phases", make)


# -- nearest-upsampled arrays, remembered under no_grad --------------------------------------
_UPSAMPLED: dict = {}


def remember_upsampled(y: np.ndarray, factor) -> None:
    """Note that ``y`` is a nearest upsampling by ``factor`` (made read-only, so that it
    stays one), so that a 3x3 convolution of it can run on the small image
    (``_phase_matrices``). Forgotten when ``y`` is freed."""
    y.flags.writeable = False
    key = id(y)
    _UPSAMPLED[key] = (weakref.ref(y, lambda _, k=key: _UPSAMPLED.pop(k, None)), factor)


def _upsampled_by_two(x: np.ndarray):
    """The small image whose nearest x2 upsampling ``x`` is (a strided view), or None."""
    entry = _UPSAMPLED.get(id(x))
    if entry is None or entry[0]() is not x or entry[1] != (2, 2):
        return None
    return x[:, :, ::2, ::2]


# -- im2col, blocked --------------------------------------------------------------------------
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


def _runs(windows: np.ndarray):
    """``windows`` (..., KH, KW, C) seen as (..., KH) runs of one opaque KW*C-float
    element each, if its window rows are contiguous and long enough to be copied
    pixel-major (else None): the same bytes, but NumPy's copy then moves a run per
    step instead of looping over its floats (a third faster)."""
    *lead, KW, C = windows.shape
    if KW * C < _SHORT_RUN or windows.strides[-2:] != (C * windows.itemsize,
                                                       windows.itemsize):
        return None
    rows = as_strided(windows, (*lead, KW * C), windows.strides[:-2] + (windows.itemsize,),
                      writeable=False)
    return rows.view(np.dtype((np.void, KW * C * windows.itemsize)))[..., 0]


def _im2col_views(block: np.ndarray, buf: np.ndarray, runs=None):
    """How a block of windows (n, r, OW, KH, KW, C) becomes the (n*r*OW, KH*KW*C) cols
    matrix in ``buf``: ``(dst, src, cols)``, where ``np.copyto(dst, src)`` fills
    ``cols`` (all three are views; nothing is copied here). ``runs``: the block as
    ``_runs`` sees it, if it does.

    The copy's cost is per contiguous run, so the memory order follows the longer run:
    pixel-major (a window row of KW*C floats) or, with few channels, tap-major (a run of
    OW output pixels per kernel tap and channel; cols is then the transpose of a
    (KH*KW*C, m) matrix).
    """
    n, r, OW, KH, KW, C = block.shape
    m, K = n * r * OW, KH * KW * C
    if KW * C >= _SHORT_RUN:
        cols = buf[:m * K].reshape(m, K)
        if runs is None:
            return cols.reshape(block.shape), block, cols
        return cols.reshape(n, r, OW, KH, KW * C).view(runs.dtype)[..., 0], runs, cols
    cols_t = buf[:m * K].reshape(K, m)
    return (cols_t.reshape(KH, KW, C, n, r, OW), block.transpose(3, 4, 5, 0, 1, 2),
            cols_t.T)


def _im2col_blocks(windows: np.ndarray):
    """The blocked im2col of ``windows``: per block ``(dst, src, cols, index)``, the
    views of ``_im2col_views`` in one scratch buffer (the first block's size: the
    largest) and the output rows ``index`` the block's cols stand for."""
    runs, buf = _runs(windows), None
    for block, index in _blocks(windows):
        if buf is None:
            buf = np.empty(block.size, dtype=windows.dtype)
        yield _im2col_views(block, buf, None if runs is None else runs[index]) + (index,)


def conv2d_nhwc(xp: np.ndarray, kernel, stride, out_hw, wmat_t: np.ndarray,
                out: np.ndarray | None = None) -> np.ndarray:
    """Channels-last convolution without bias: ``y = cols @ wmat_t``, (N, OH, OW, O).

    ``xp`` is the zero-padded input, channels-last (N, Hp, Wp, C); ``wmat_t`` the weight
    as a (KH*KW*C, O) matrix (rows ordered like a cols row). Block by block: im2col
    one block into a scratch buffer, one GEMM into its rows of ``out``."""
    N, (OH, OW), O = xp.shape[0], out_hw, wmat_t.shape[1]
    y = np.empty((N, OH, OW, O), dtype=xp.dtype) if out is None else out
    for dst, src, cols, index in _im2col_blocks(_windows(xp, kernel, stride, out_hw)):
        np.copyto(dst, src)
        np.matmul(cols, wmat_t, out=y[index].reshape(len(cols), O))
    return y


def conv_weight_grad(xp: np.ndarray, kernel, stride, g: np.ndarray) -> np.ndarray:
    """``cols^T @ G`` = dL/dW as a (KH*KW*C, O) matrix, for ``g`` (N, OH, OW, O)
    channels-last; cols is rebuilt block by block from ``xp`` (cheaper than keeping
    it: see ``_BLOCK_BYTES``)."""
    windows = _windows(xp, kernel, stride, g.shape[1:3])
    K, O = windows[0, 0, 0].size, g.shape[3]
    total = np.zeros((K, O), dtype=xp.dtype)
    for dst, src, cols, index in _im2col_blocks(windows):
        np.copyto(dst, src)
        total += cols.T @ g[index].reshape(len(cols), O)
    return total


# -- plans: a forward convolution's schedule, built once per input shape --------------------
class _Blocks:
    """The im2col schedule of one convolution over a fixed padded input buffer ``xp``:
    ``steps`` lists, per block, ``(dst, src, cols, index)``: ``np.copyto(dst, src)``
    writes its cols into one scratch buffer and ``cols @ W^T`` goes to output rows
    ``index``."""

    def __init__(self, xp: np.ndarray, kernel, stride, out_hw):
        self.steps = list(_im2col_blocks(_windows(xp, kernel, stride, out_hw)))

    def run(self, wmat_t: np.ndarray, y: np.ndarray) -> np.ndarray:
        O = y.shape[3]
        for dst, src, cols, index in self.steps:
            np.copyto(dst, src)
            np.matmul(cols, wmat_t, out=y[index].reshape(len(cols), O))
        return y


class _Plan:
    """How one forward convolution runs for one input shape, under ``no_grad``.

    ``xp``: the padded channels-last input buffer (its border zeros, never written).
    ``kind``: "im2col" (``blocks``), "contract" (channels first: ``contract`` holds
    the tap matrix product's views) or "phases" (a 3x3 conv of a nearest-x2-upsampled
    image on the small image: ``phases`` maps (p, q) to the blocks of a 2x2 conv of
    the window of ``xp`` at (p, q), written into ``part``)."""

    def __init__(self, shape, dtype, kernel, stride, padding, out_hw, out_channels, kind):
        N, C, H, W = shape
        (KH, KW), (ph, pw), (OH, OW) = kernel, padding, out_hw
        self.kind = kind
        self.xp = np.zeros((N, H + 2 * ph, W + 2 * pw, C), dtype)
        if kind == "im2col":
            self.blocks = _Blocks(self.xp, kernel, stride, out_hw)
        elif kind == "contract":
            O, Hp, Wp = out_channels, H + 2 * ph, W + 2 * pw
            P = np.empty((KH * KW * O, N * Hp * Wp), dtype)
            taps = P.reshape(KH, KW, O, N, Hp, Wp)
            shifted = [taps[i, j, :, :, i:i + OH, j:j + OW]
                       for i in range(KH) for j in range(KW)]
            self.contract = (self.xp.reshape(N * Hp * Wp, C).T, P, shifted)
        else:                                 # shape is the small image's; padding 1
            self.phases = {(p, q): _Blocks(self.xp[:, p:p + H + 1, q:q + W + 1], (2, 2),
                                           (1, 1), (H, W)) for p in (0, 1) for q in (0, 1)}
            self.part = np.empty((N, H, W, out_channels), dtype)


_LOCAL = threading.local()


def _plan(shape, dtype, kernel, stride, padding, out_hw, out_channels, kind) -> _Plan:
    plans = getattr(_LOCAL, "plans", None)
    if plans is None:
        plans = _LOCAL.plans = OrderedDict()
    key = (shape, dtype, kernel, stride, padding, out_channels, kind, _BLOCK_BYTES)
    plan = plans.get(key)
    if plan is None:
        plan = plans[key] = _Plan(shape, dtype, kernel, stride, padding, out_hw,
                                  out_channels, kind)
        if len(plans) > _MAX_PLANS:
            plans.popitem(last=False)
    else:
        plans.move_to_end(key)
    return plan


def conv2d_forward(x: np.ndarray, weight, kernel, stride, padding, out_hw,
                   keep_input: bool):
    """The forward convolution ``cols @ W^T`` of NCHW-shaped ``x`` (no bias).

    Returns ``(y, xp)``: ``y`` a fresh channels-last (N, OH, OW, O) array; ``xp`` the
    padded channels-last input, which dL/dW will read, if ``keep_input`` (a fresh
    array, or ``x`` itself when nothing is padded); else None (the plan's buffer was
    used, and will be again)."""
    O = weight.shape[0]
    (KH, KW), (ph, pw) = kernel, padding
    N, (OH, OW) = x.shape[0], out_hw
    if keep_input:                           # the backward pass keeps this one
        if ph == pw == 0 and channels_last(x):           # nothing to pad or move
            xp = x.transpose(0, 2, 3, 1)
        else:
            xp = pad_nhwc(x, ph, pw)
        return conv2d_nhwc(xp, kernel, stride, out_hw, weight_matrix(weight)), xp
    y = np.empty((N, OH, OW, O), x.dtype)
    small = None
    if kernel == (3, 3) and stride == (1, 1) and padding == (1, 1):
        small = _upsampled_by_two(x)
    if small is not None:
        plan = _plan(small.shape, x.dtype, kernel, stride, padding, out_hw, O, "phases")
        pad_nhwc(small, 1, 1, out=plan.xp)
        weights = _phase_matrices(weight)
        for (p, q), blocks in plan.phases.items():
            _copy_pixels(y[:, p::2, q::2], blocks.run(weights[p, q], plan.part))
        return y, None
    kind = "contract" if stride == (1, 1) and KH * KW * O <= x.shape[1] else "im2col"
    plan = _plan(x.shape, x.dtype, kernel, stride, padding, out_hw, O, kind)
    pad_nhwc(x, ph, pw, out=plan.xp)
    if kind == "im2col":
        return plan.blocks.run(weight_matrix(weight), y), None
    # P[(i, j, o), n, y, x] = sum_c w[o, c, i, j] xp[n, y, x, c], then
    # y[n, u, v, o] = sum_{i, j} P[(i, j, o), n, u + i, v + j].
    x_t, P, shifted = plan.contract
    np.matmul(_tap_matrix(weight), x_t, out=P)
    acc = y.transpose(3, 0, 1, 2)                          # (O, N, OH, OW) view of y
    np.copyto(acc, shifted[0])
    for tap in shifted[1:]:
        np.add(acc, tap, out=acc)
    return y, None


# -- the input gradient: a transposed convolution -------------------------------------------
def transposed_conv(g: np.ndarray, weight: np.ndarray, stride, origin, out_hw
                    ) -> np.ndarray:
    """The adjoint of a convolution's input, channels-last, on a window of its input.

    ``g`` (N, OH, OW, O) channels-last, ``weight`` (O, C, KH, KW). Returns ``z`` (N,
    Hz, Wz, C) with, for padded-input pixel (Y, X) = (y0 + r, x0 + q),

        z[n, r, q, c] = sum_{u, i: s u + i = Y} sum_{v, j: s v + j = X}
                        sum_o g[n, u, v, o] w[o, c, i, j]

    (col2im of ``g @ W``). Rows with Y = s Y' + a (phase a) only meet the taps
    i = a + s i', at u = Y' - i': a stride-1 correlation of ``g`` with the flipped
    taps ``w[:, :, a::s]``. ``g`` is zero-padded once for all phases; per phase (a, b):
    im2col of its window of that, one GEMM, and the result written to
    ``z[:, a'::s, b'::s]`` pixel by pixel.
    """
    N, OH, OW, O = g.shape
    _, C, KH, KW = weight.shape
    (sh, sw), (y0, x0), (Hz, Wz) = stride, origin, out_hw
    z = None if sh == sw == 1 else np.empty((N, Hz, Wz, C), dtype=g.dtype)
    # per axis and phase: (first row of z in the phase, its Y', rows, taps)
    rows = [_phase_span(a, y0, Hz, sh, KH) for a in range(sh)]
    cols = [_phase_span(b, x0, Wz, sw, KW) for b in range(sw)]
    # one zero-padded copy of g serves every phase: phase (a, b) reads its window
    # gp[t] = g[lo_y - ka + 1 + t] (zero outside 0..OH-1), window t..t+ka-1
    live_rows = [(lo - k + 1, lo + n) for _, lo, n, k in rows if n and k]
    live_cols = [(lo - k + 1, lo + n) for _, lo, n, k in cols if n and k]
    if not (live_rows and live_cols):                     # no tap reaches the window
        z[...] = 0
        return z
    (u_lo, _), (v_lo, _) = min(live_rows), min(live_cols)
    u_hi, v_hi = max(hi for _, hi in live_rows), max(hi for _, hi in live_cols)
    shared = _padded_rows(g, u_lo, u_hi - u_lo, v_lo, v_hi - v_lo)
    for a, (r0, lo_y, ny, ka) in enumerate(rows):
        for b, (q0, lo_x, nx, kb) in enumerate(cols):
            if ny == 0 or nx == 0:
                continue
            if ka == 0 or kb == 0:                        # stride > kernel: no tap
                z[:, r0::sh, q0::sw] = 0
                continue
            u0, v0 = lo_y - ka + 1 - u_lo, lo_x - kb + 1 - v_lo
            gp = shared[:, u0:u0 + ny + ka - 1, v0:v0 + nx + kb - 1]
            taps = weight[:, :, a::sh, b::sw]             # (O, C, ka, kb)
            flipped = taps[:, :, ::-1, ::-1].transpose(2, 3, 0, 1).reshape(ka * kb * O, C)
            part = conv2d_nhwc(gp, (ka, kb), (1, 1), (ny, nx), flipped)
            if z is None:                                 # stride 1: a single phase
                return part
            _copy_pixels(z[:, r0::sh, q0::sw], part)
    return z


def _copy_pixels(dst: np.ndarray, src: np.ndarray) -> None:
    """``dst[...] = src`` for two (..., C) arrays whose pixels (the last axis) are
    contiguous, each pixel copied as one opaque element of C floats (NumPy's copy
    then moves a pixel per step instead of looping over a few floats)."""
    pixel = np.dtype((np.void, src.shape[-1] * src.itemsize))
    np.copyto(dst.view(pixel)[..., 0], src.view(pixel)[..., 0])


def _phase_span(a: int, y0: int, Hz: int, s: int, K: int):
    """Phase ``a`` of a stride-``s`` axis seen from a window starting at padded-input
    row ``y0``, ``Hz`` rows long: (its first row of the window, that row's Y' = (y0 +
    r0 - a) / s, how many rows of the window are in it, its taps ``len(range(a, K,
    s))``)."""
    r0 = (a - y0) % s
    return r0, (y0 + r0 - a) // s, len(range(r0, Hz, s)), len(range(a, K, s))


def _padded_rows(g: np.ndarray, u0: int, nu: int, v0: int, nv: int) -> np.ndarray:
    """``gp[:, t, q] = g[:, u0 + t, v0 + q]`` for t < nu, q < nv, zero outside ``g``."""
    N, OH, OW, O = g.shape
    gp = np.zeros((N, nu, nv, O), dtype=g.dtype)
    us, ue, vs, ve = max(u0, 0), min(u0 + nu, OH), max(v0, 0), min(v0 + nv, OW)
    if us < ue and vs < ve:
        gp[:, us - u0:ue - u0, vs - v0:ve - v0] = g[:, us:ue, vs:ve]
    return gp


# -- nearest upsampling and concatenation, layout-preserving ---------------------------------
def repeat_nearest(x: np.ndarray, sh: int, sw: int, remember: bool = False) -> np.ndarray:
    """``np.repeat(np.repeat(x, sh, 2), sw, 3)`` for NCHW ``x``, in ``x``'s layout:
    sh*sw strided copies, output pixel (sh i + a, sw j + b) = x[i, j]. ``remember``:
    ``remember_upsampled`` (the result is then read-only)."""
    N, C, H, W = x.shape
    y = empty_like_layout((N, C, sh * H, sw * W), x)
    for a in range(sh):
        for b in range(sw):
            _assign(y[:, :, a::sh, b::sw], x)
    if remember:
        remember_upsampled(y, (sh, sw))
    return y


def concatenate(arrays, axis: int) -> np.ndarray:
    """``np.concatenate(arrays, axis)``, stored channels-last if the first array is
    (NCHW arrays joined along the channels)."""
    first = arrays[0]
    same = all(a.ndim == 4 and a.shape[:1] + a.shape[2:] == first.shape[:1] + first.shape[2:]
               for a in arrays)
    if not (same and axis in (1, -3) and channels_last(first)):
        return np.concatenate(arrays, axis=axis)
    shape = list(first.shape)
    shape[1] = sum(a.shape[1] for a in arrays)
    y = empty_like_layout(tuple(shape), first)
    c = 0
    for a in arrays:
        _assign(y[:, c:c + a.shape[1]], a)
        c += a.shape[1]
    return y


def _assign(dst: np.ndarray, src: np.ndarray) -> None:
    """``dst[...] = src`` for NCHW-shaped arrays; pixel by pixel (``_copy_pixels``)
    when both keep a pixel's channels contiguous."""
    if dst.strides[1] == src.strides[1] == src.itemsize and dst.dtype == src.dtype:
        _copy_pixels(dst.transpose(0, 2, 3, 1), src.transpose(0, 2, 3, 1))
    else:
        dst[...] = src
