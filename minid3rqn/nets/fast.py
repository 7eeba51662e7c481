"""The graph-free inference paths: allocation-aware copies of the networks' ``forward``.

The networks a student reads (``nets/qnet.py``, ``nets/dispnet.py``) compute their
output one way, ``forward``, through the autograd ops: training needs the graph those
ops record. Acting and depth inference do not, and at batch 1 the graph's bookkeeping
(Tensor wrappers, argument checks, weights re-laid out on every call, NCHW <->
channels-last copies) cost as much as the arithmetic. This module holds copies of those
``forward`` passes on plain arrays, with buffers allocated once, kept apart from the
teaching code as minitorch keeps its ``fast_ops``. They call the same convolution
routine (``autograd.conv.conv2d_nhwc``) and keep the same order of operations wherever
they can; tests/test_fast_inference.py keeps them equal to ``forward``.

    ConvInference          one convolution, its weights laid out once (channels-last)
    upsample_conv_phases   "nearest upsample x2, conv 3x3" as four 2x2 convolutions
    bias_elu_              bias + ELU in place, without allocating
    qnet_step              ``QNet.step`` (one time step, acting) on plain arrays; reads the
                           current weights on every call
    DispNetInference       ``DispNet.forward(x, scales=1)[0]`` on a snapshot of the weights,
                           channels-last, into preallocated buffers
"""
from __future__ import annotations

import numpy as np

from .. import autograd as ag
from ..autograd import Tensor
from ..autograd.conv import (_int_pair, conv2d_nhwc, conv2d_nhwc_plan, im2col_work_size,
                             run_conv_plan)
from ..autograd.elementwise import _stable_sigmoid
from ..autograd.lstm import _gates
from .dispnet import RGB_MEAN, RGB_STD, DispNet
from .layers import Conv2d, Linear
from .qnet import QNet


# -- building blocks ---------------------------------------------------------------------
class ConvInference:
    """A convolution's weights frozen for inference: channels-last arrays in and out, no
    autograd graph. ``ConvInference(conv2d_layer)`` or ``ConvInference.of(weight, bias,
    stride, padding)``; call it, or ``bind`` it to fixed buffers.

    The weight is laid out once; the call runs what ``ag.conv2d``'s forward runs,
    ``autograd.conv.conv2d_nhwc``, so the two give the same numbers, to the last bit.
    One exception, for layers with very few output channels (KH*KW*C_out <= C_in, stride
    1: a disparity head): the channels are contracted first, ``P[t] = xp @ w[:, :, t]``
    for each kernel tap t (one small GEMM, no im2col), and the output is the sum of the
    KH*KW tap images shifted by their offsets: the same products summed in another
    order, equal to float round-off, not to the bit.

    A *snapshot*: later changes to the layer's weights are not seen; build a new one.

    Call: ``xp`` (N, H + 2 p_h, W + 2 p_w, C) the input, channels-last and already
    zero-padded -> (N, OH, OW, C_out) without the bias (see ``bias_elu_``); ``out`` and
    ``work`` as in ``conv2d_nhwc`` (preallocated output and im2col scratch).
    """

    def __init__(self, conv: Conv2d):
        self._setup(conv.weight.data, None if conv.bias is None else conv.bias.data,
                    conv.stride, conv.padding)

    @classmethod
    def of(cls, weight: np.ndarray, bias=None, stride=1, padding=0) -> "ConvInference":
        """From arrays: weight (C_out, C_in, KH, KW), bias (C_out,) or None."""
        self = cls.__new__(cls)
        self._setup(np.asarray(weight), None if bias is None else np.asarray(bias),
                    stride, padding)
        return self

    def _setup(self, w, bias, stride, padding):
        O, C, KH, KW = w.shape
        # The (O, KH*KW*C) matrix, used transposed: exactly the operand ag.conv2d builds,
        # so BLAS runs the same kernel on the same memory layout (same rounding).
        wmat = np.ascontiguousarray(w.transpose(0, 2, 3, 1).reshape(O, KH * KW * C))
        self.wmat_t = wmat.T
        self.bias = None if bias is None else bias.copy()
        self.kernel = (KH, KW)
        self.stride = _int_pair(stride, "stride", "Conv2d", 1)
        self.padding = _int_pair(padding, "padding", "Conv2d", 0)
        self.in_channels, self.out_channels = C, O
        self.contract_first = self.stride == (1, 1) and KH * KW * O <= C
        # (KH*KW*O, C): row (i*KW + j)*O + o holds w[o, :, i, j]
        self.taps = (np.ascontiguousarray(w.transpose(2, 3, 0, 1).reshape(KH * KW * O, C))
                     if self.contract_first else None)

    def out_hw(self, h: int, w: int) -> tuple[int, int]:
        """Output size for an (h, w) input (before padding)."""
        (KH, KW), (sh, sw), (ph, pw) = self.kernel, self.stride, self.padding
        return (h + 2 * ph - KH) // sh + 1, (w + 2 * pw - KW) // sw + 1

    def work_size(self, xp: np.ndarray) -> int:
        """Elements of scratch ``__call__`` needs for an input shaped like ``xp``."""
        N, Hp, Wp, _ = xp.shape
        (ph, pw) = self.padding
        hw = self.out_hw(Hp - 2 * ph, Wp - 2 * pw)
        if self.contract_first:
            return len(self.taps) * N * Hp * Wp
        return im2col_work_size(xp, self.kernel, self.stride, hw)

    def __call__(self, xp: np.ndarray, out=None, work=None) -> np.ndarray:
        N, Hp, Wp, _ = xp.shape
        (ph, pw) = self.padding
        OH, OW = self.out_hw(Hp - 2 * ph, Wp - 2 * pw)
        y = np.empty((N, OH, OW, self.out_channels), xp.dtype) if out is None else out
        if not self.contract_first:                       # what ag.conv2d runs
            return conv2d_nhwc(xp, self.kernel, self.stride, (OH, OW), self.wmat_t, y, work)
        if work is None:
            work = np.empty(self.work_size(xp), xp.dtype)
        self.bind(np.ascontiguousarray(xp), y, work)()
        return y

    def bind(self, xp: np.ndarray, out: np.ndarray, work: np.ndarray):
        """A function of no arguments that computes this layer from ``xp`` into ``out``
        (no bias), with every strided view prepared now, for buffers reused call after
        call (``DispNetInference``)."""
        (ph, pw) = self.padding
        hw = self.out_hw(xp.shape[1] - 2 * ph, xp.shape[2] - 2 * pw)
        if not self.contract_first:
            plan = conv2d_nhwc_plan(xp, self.kernel, self.stride, hw, out, work)
            wmat_t = self.wmat_t
            return lambda: run_conv_plan(plan, wmat_t)
        # Contract channels first:
        #   P[(i, j, o), n, y, x] = sum_c w[o, c, i, j] xp[n, y, x, c],
        # then
        #   y[n, u, v, o] = sum_{i, j} P[(i, j, o), n, u + i, v + j].
        N, Hp, Wp, C = xp.shape
        (KH, KW), (OH, OW), O = self.kernel, hw, self.out_channels
        if not xp.flags.c_contiguous:
            raise ValueError("ConvInference.bind: a contract-first layer needs a "
                             "C-contiguous input buffer")
        x_t = xp.reshape(N * Hp * Wp, C).T
        P = work[:len(self.taps) * N * Hp * Wp].reshape(len(self.taps), N * Hp * Wp)
        taps = P.reshape(KH, KW, O, N, Hp, Wp)
        shifted = [taps[i, j, :, :, i:i + OH, j:j + OW]
                   for i in range(KH) for j in range(KW)]
        acc = out.transpose(3, 0, 1, 2)                     # (O, N, OH, OW) view of out
        weights = self.taps

        def run():
            np.matmul(weights, x_t, out=P)                  # one small GEMM, no im2col
            np.copyto(acc, shifted[0])
            for tap in shifted[1:]:                         # y = sum of shifted taps
                np.add(acc, tap, out=acc)
        return run


def upsample_conv_phases(weight: np.ndarray) -> dict:
    """A 3x3 convolution (padding 1) of a nearest-x2-upsampled image, as four 2x2
    convolutions of the small image, one per output phase.

    Output pixel (2a + p, 2b + q) of ``conv3x3(upsample2(x))`` reads upsampled rows
    2a + p - 1 .. 2a + p + 1, i.e. small rows (a - 1, a, a) for p = 0 and (a, a, a + 1)
    for p = 1 (zero padding agrees: upsampled row -1 or 2H is small row -1 or H), so
    the taps that read the same small row can be summed: rows (a - 1, a) with weights
    (w0, w1 + w2) for p = 0, rows (a, a + 1) with (w0 + w1, w2) for p = 1; the same
    along columns. With the small image zero-padded by 1, phase (p, q) is a 2x2
    convolution, stride 1, of its window starting at (p, q). That is 4 x 4 = 16 instead
    of 4 x 9 = 36 multiply-adds per small pixel and channel pair, and a 4/9-size im2col.

    weight (O, C, 3, 3) -> {(p, q): weight (O, C, 2, 2)}.
    """
    if weight.shape[2:] != (3, 3):
        raise ValueError(f"upsample_conv_phases: needs a 3x3 kernel; got {weight.shape}")
    rows = {0: lambda w: np.stack([w[:, :, 0], w[:, :, 1] + w[:, :, 2]], axis=2),
            1: lambda w: np.stack([w[:, :, 0] + w[:, :, 1], w[:, :, 2]], axis=2)}
    cols = {0: lambda w: np.stack([w[..., 0], w[..., 1] + w[..., 2]], axis=3),
            1: lambda w: np.stack([w[..., 0] + w[..., 1], w[..., 2]], axis=3)}
    return {(p, q): cols[q](rows[p](weight)) for p in (0, 1) for q in (0, 1)}


def bias_elu_(y: np.ndarray, bias, scratch: np.ndarray, zeros: np.ndarray) -> np.ndarray:
    """In place: ``y <- ELU(y + bias)`` (alpha = 1), as ``max(x, 0) + (exp(min(x, 0)) - 1)``.

    ``ag.elu`` (training) computes ``where(x > 0, x, expm1(min(x, 0)))``; NumPy
    vectorizes ``exp`` on any x86-64 CPU but ``expm1`` only with AVX-512
    (``benchmarks/bench_dispnet_chunk.py --elu``). For x > 0 the result is x to the bit;
    for x <= 0, ``exp(x) - 1`` is exact when exp(x) >= 1/2 (Sterbenz), so the error is
    ``exp``'s rounding, at most about 1.2e-7 absolute in float32.

    No ``np.where`` and no allocation: ``scratch`` and ``zeros`` are arrays of ``y``'s
    shape and dtype (``zeros`` all zeros: NumPy's SIMD min/max loops want two
    contiguous operands).
    """
    if bias is not None:
        y += bias
    np.minimum(y, zeros, out=scratch)
    np.maximum(y, zeros, out=y)
    np.exp(scratch, out=scratch)
    scratch -= y.dtype.type(1)          # exact for exp(x) in [1/2, 1]; 0 where x >= 0
    y += scratch
    return y


# -- the Q-network's acting step ---------------------------------------------------------
def qnet_step(net: QNet, obs, state=None):
    """``net.step(obs, state)``: one time step, obs (B, C, H, W) -> (Q (B, n_actions),
    new state), for acting (the policies, the agent's epsilon-greedy steps).

    Under ``no_grad`` this runs ``_qnet_step_arrays``; with gradients on, ``net.step``.
    """
    obs = obs.data if isinstance(obs, Tensor) else np.asarray(obs)
    if not ag.is_grad_enabled() and _arrays_ok(net, obs, state):
        return _qnet_step_arrays(net, obs, state)
    return net.step(obs, state)


def _arrays_ok(net: QNet, obs: np.ndarray, state) -> bool:
    """Inputs the graph-free step handles; anything else (wrong shapes or dtypes)
    goes to ``net.step``, whose ``forward`` raises the usual errors."""
    cfg, dtype = net.config, net.convs[0].weight.dtype
    expected = (cfg.in_channels, cfg.height, cfg.width_px)
    if obs.ndim != 4 or obs.shape[1:] != expected or obs.dtype != dtype:
        return False
    if state is None or not net.recurrent:
        return True
    return all(np.shape(s) == (obs.shape[0], cfg.width) and
               (s.dtype if isinstance(s, Tensor) else np.asarray(s).dtype) == dtype
               for s in state)


def _qnet_step_arrays(net: QNet, obs: np.ndarray, state):
    """``net.step`` on plain arrays: the operations of ``QNet.forward`` (T = 1), in the
    same order and with the same routines (``conv2d_nhwc`` through ``ConvInference``,
    the LSTM's ``_gates``), so Q and the state come out the same, to the bit. Reads the
    current weights on every call, so it is safe while the network trains."""
    B = obs.shape[0]
    x = np.ascontiguousarray(obs.transpose(0, 2, 3, 1))        # channels-last
    for conv in net.convs:
        layer = ConvInference(conv)                   # valid convolution: no padding
        x = layer(x)
        if layer.bias is not None:
            x += layer.bias
        np.multiply(x, x > 0, out=x)                  # ReLU, as ag.relu computes it
    z = x.transpose(0, 3, 1, 2).reshape(B, net.n_features)    # NCHW order, as flatten
    if net.recurrent:
        core, H = net.core, net.config.width
        if state is None:
            h = np.zeros((B, H), z.dtype)
            c = np.zeros((B, H), z.dtype)
        else:
            h, c = (s.data if isinstance(s, Tensor) else np.asarray(s) for s in state)
        gates = z @ core.weight_ih.data.T
        gates += core.bias.data
        gates += h @ core.weight_hh.data.T
        _gates(gates, H)
        i, f = gates[:, :H], gates[:, H:2 * H]
        g, o = gates[:, 2 * H:3 * H], gates[:, 3 * H:]
        c = f * c + i * g
        h = o * np.tanh(c)
        z, state = h, (Tensor(h), Tensor(c))
    else:
        z = _linear(z, net.core)
        np.multiply(z, z > 0, out=z)
        state = None
    z = z[None]                                        # (1, B, width), as forward
    if net.config.dueling:
        value, adv = _linear(z, net.value), _linear(z, net.advantage)
        q = value + (adv - np.mean(adv, axis=(-1,), keepdims=True).astype(adv.dtype))
    else:
        q = _linear(z, net.q_head)
    return Tensor(q[0]), state


def _linear(x: np.ndarray, layer: Linear) -> np.ndarray:
    """``layer(x)`` on arrays: x W^T + b."""
    y = x @ layer.weight.data.T
    return y + layer.bias.data if layer.bias is not None else y


# -- the DispNet -------------------------------------------------------------------------
class DispNetInference:
    """``DispNet.forward(x, scales=1)[0]`` without autograd: a snapshot for inference.

    The same computation with the same convolution routine (``ConvInference`` ->
    ``autograd.conv.conv2d_nhwc``), but

    - keeps activations channels-last (N, H, W, C) from input to output;
    - writes each layer's result straight into the zero-padded input buffer of the
      layer that reads it (in the decoder: upsampled into the first channels, the
      encoder's skip features into the last ones, so "upsample, crop, concat, pad" is
      a few strided copies); the buffers are allocated once per batch size;
    - applies bias + ELU in place (``bias_elu_``, ``exp(x) - 1`` for ``expm1(x)``);
    - computes only the finest disparity head, the one inference uses;
    - at a decoder level without skip features and without cropping (the finest one,
      the largest layer), runs "upsample x2, conv 3x3" as four 2x2 convolutions of
      the small image (``upsample_conv_phases``: 4/9 of the work), and the 1-channel
      head by contracting channels first (``ConvInference``).

    The last two sum the same products in another order, and the ELU rounds its
    negative side differently, so the output equals ``forward`` to float round-off
    (about 1e-6 relative in float32), not to the bit.

    Large batches run ``chunk`` frames at a time, so that the working set (about 1 MB
    of buffers per frame at 32x104) stays in the CPU caches; the chunk changes the last
    bit of some outputs (the GEMMs' row counts change), so the default stays 8.

    A snapshot: weights changed after construction are not seen. Not thread-safe (the
    buffers are shared): one instance per thread.
    """

    def __init__(self, net: DispNet, chunk: int = 8):
        self.enc_a = [ConvInference(c) for c in net.enc_a]
        self.enc_b = [ConvInference(c) for c in net.enc_b]
        self.dec_a = [ConvInference(c) for c in net.dec_a]
        self.dec_b = [ConvInference(c) for c in net.dec_b]
        # dec_b as four phase convolutions, where it applies (see _phase_split)
        self.dec_b_phases = [self._phase_split(conv, a.out_channels)
                             for conv, a in zip(net.dec_b, self.dec_a)]
        self.head = ConvInference(net.heads[0])
        self.dtype = net.heads[0].weight.dtype
        self.disp_scale, self.min_disp = net.disp_scale, net.min_disp
        self.chunk = max(1, int(chunk))
        self._workspaces: dict[tuple, dict] = {}

    @staticmethod
    def _phase_split(conv: Conv2d, up_channels: int):
        """{(p, q): ConvInference 2x2} if ``conv`` reads only upsampled features (no skip
        channels) with a 3x3 kernel, stride 1, padding 1; else None."""
        ok = (conv.weight.shape[1] == up_channels and conv.weight.shape[2:] == (3, 3)
              and conv.stride in (1, (1, 1)) and conv.padding in (1, (1, 1)))
        if not ok:
            return None
        bias = None if conv.bias is None else conv.bias.data
        return {pq: ConvInference.of(w, bias) for pq, w in
                upsample_conv_phases(conv.weight.data).items()}

    # -- buffers -------------------------------------------------------------------------
    def _workspace(self, n: int, h: int, w: int) -> dict:
        """Every buffer a forward of ``n`` frames of h x w needs (cached for a few n), and
        each convolution bound to its buffers (``ConvInference.bind``): a level's entry
        ``"a"``, ``"b"`` or ``(p, q)`` is a function that computes ELU(conv + b) into
        the level's output buffer and returns it."""
        key = (n, h, w)
        if key in self._workspaces:                       # most recently used goes last
            self._workspaces[key] = self._workspaces.pop(key)
            return self._workspaces[key]
        if len(self._workspaces) >= 4:                    # bound the memory kept: drop
            self._workspaces.pop(next(iter(self._workspaces)))   # the least recently used
        dt, convs = self.dtype, []

        def padded(hh, ww, c):      # every DispNet conv is 3x3 with padding 1: a border
            return np.zeros((n, hh + 2, ww + 2, c), dt)   # of zeros, never written

        def conv(level, name, layer, xp, y=None):  # output buffer now, bound below
            if y is None:
                oh, ow = layer.out_hw(xp.shape[1] - 2 * layer.padding[0],
                                      xp.shape[2] - 2 * layer.padding[1])
                y = np.empty((n, oh, ow, layer.out_channels), dt)
            convs.append((level, name, layer, xp, y))
            return y

        x = first = padded(h, w, 3)
        enc = []
        for conv_a, conv_b in zip(self.enc_a, self.enc_b):
            level = {}
            y = conv(level, "a", conv_a, x)
            level["xb"] = padded(*y.shape[1:])
            y = conv(level, "b", conv_b, level["xb"])
            x = level["x_next"] = padded(*y.shape[1:])    # the next conv's input
            enc.append(level)
        dec = []
        levels = len(self.enc_a)
        for j, i in enumerate(reversed(range(levels))):
            level = {}
            y = conv(level, "a", self.dec_a[j], x)
            th, tw = -(-h // 2 ** i), -(-w // 2 ** i)       # ceil(h / 2^i), as forward
            phases = self.dec_b_phases[j]
            if phases is not None and (th, tw) == (2 * y.shape[1], 2 * y.shape[2]):
                hh, ww = y.shape[1:3]
                level["up"] = padded(*y.shape[1:])
                y_phase = None                            # one output buffer, reused
                for (p, q), layer in phases.items():      # phase (p, q)'s window
                    window = level["up"][:, p:p + hh + 1, q:q + ww + 1]
                    y_phase = conv(level, (p, q), layer, window, y_phase)
            else:
                level["xb"] = padded(th, tw, self.dec_b[j].in_channels)
                conv(level, "b", self.dec_b[j], level["xb"])
            x = level["x_next"] = padded(th, tw, self.dec_b[j].out_channels)
            dec.append(level)
        head = {}
        z = conv(head, "z", self.head, x)                 # (n, h, w, 1)
        work = np.empty(max(layer.work_size(xp) for _, _, layer, xp, _ in convs), dt)
        size = max(y.size for *_, y in convs)
        scratch, zeros = np.empty(size, dt), np.zeros(size, dt)
        for level, name, layer, xp, y in convs:
            run = layer.bind(xp, y, work)
            if level is head:
                level[name] = run
            else:
                level[name] = _with_bias_elu(run, layer.bias, y, _like(scratch, y),
                                             _like(zeros, y))
        ws = {"input": first, "enc": enc, "dec": dec, "head": head["z"], "z": z[..., 0]}
        self._workspaces[key] = ws
        return ws

    # -- the forward pass ----------------------------------------------------------------
    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        """rgb (N, H, W, 3) channels-last, uint8 (0..255) or float in [0, 1] ->
        disparity (N, H, W) at the finest scale (the network's dtype)."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 4 or rgb.shape[-1] != 3:
            raise ValueError(f"DispNetInference: rgb must be (N, H, W, 3); got {rgb.shape}")
        out = np.empty(rgb.shape[:3], self.dtype)
        for k in range(0, len(rgb), self.chunk):
            self._forward(rgb[k:k + self.chunk], out[k:k + self.chunk])
        return out

    def _forward(self, rgb: np.ndarray, out: np.ndarray) -> None:
        n, h, w, _ = rgb.shape
        ws = self._workspace(n, h, w)
        dt = self.dtype
        # The input, normalised as DispNet.forward does, into the first padded buffer.
        x = ws["input"]
        inner = x[:, 1:-1, 1:-1]
        if rgb.dtype == np.uint8:                         # = astype(dt) * (1 / 255)
            np.multiply(rgb, dt.type(1 / 255.0), out=inner)
        else:
            inner[...] = rgb
        inner -= dt.type(RGB_MEAN)
        inner *= dt.type(1.0 / RGB_STD)
        levels, dec = len(self.enc_a), ws["dec"]
        for lvl, level in enumerate(ws["enc"]):           # conv s2 + ELU, conv + ELU
            level["xb"][:, 1:-1, 1:-1] = level["a"]()
            y = level["b"]()
            level["x_next"][:, 1:-1, 1:-1] = y            # the next conv's padded input
            if lvl < levels - 1:         # skip features, read by decoder level lvl + 1:
                skip_in = dec[levels - 2 - lvl]["xb"]     # the last channels of its input
                skip_in[:, 1:-1, 1:-1, -y.shape[3]:] = y
        for level in dec:
            up = level["a"]()
            x = level["x_next"]
            th, tw = x.shape[1] - 2, x.shape[2] - 2
            if "up" in level:                 # conv3x3(upsample(up)) as 4 phase convs
                level["up"][:, 1:-1, 1:-1] = up
                for p, q in ((0, 0), (0, 1), (1, 0), (1, 1)):
                    x[:, 1 + p:1 + th:2, 1 + q:1 + tw:2] = level[p, q]()
                continue
            # Nearest x2 upsampling cropped to the skip's size, into the first channels
            # of dec_b's padded input: output pixel (2u + p, 2v + q) = up[u, v].
            xb, c = level["xb"], up.shape[3]
            for p in (0, 1):
                for q in (0, 1):
                    rows, cols = len(range(p, th, 2)), len(range(q, tw, 2))
                    xb[:, 1 + p:1 + th:2, 1 + q:1 + tw:2, :c] = up[:, :rows, :cols]
            x[:, 1:-1, 1:-1] = level["b"]()
        ws["head"]()                                      # the finest head only
        z = ws["z"]                                       # (n, h, w)
        if self.head.bias is not None:
            z += self.head.bias[0]
        np.multiply(_stable_sigmoid(z), dt.type(self.disp_scale), out=out)
        out += dt.type(self.min_disp)


def _with_bias_elu(run, bias, y, scratch, zeros):
    """``run`` (a bound conv writing ``y``) followed by ``y <- ELU(y + bias)``."""
    def step():
        run()
        return bias_elu_(y, bias, scratch, zeros)
    return step


def _like(buf: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The first y.size elements of the flat ``buf``, shaped like ``y``."""
    return buf[:y.size].reshape(y.shape)
