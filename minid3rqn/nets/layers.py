"""Layers: Linear, Conv2d, LSTM, Sequential and parameter-free activations.

Every layer takes ``rng`` (a seed or ``np.random.Generator``) for its initial weights,
so the same seed builds the same network.

At the end: ``ConvInference``, ``upsample_conv_phases`` and ``bias_elu_``, the building
blocks of the graph-free inference paths (``nets.dispnet.DispNetInference``,
``QNet.step`` under ``no_grad``). Training always goes through the layers above and
the autograd ops; these only *evaluate* a layer faster.
"""
from __future__ import annotations

import numpy as np

from .. import autograd as ag
from ..autograd import Tensor
from ..autograd.conv import (_int_pair, conv2d_nhwc, conv2d_nhwc_plan, im2col_work_size,
                             run_conv_plan)
from .init import as_rng, kaiming_uniform, uniform_fan_in
from .module import Module


def _positive(name: str, value) -> int:
    if not isinstance(value, (int, np.integer)) or value <= 0:
        raise ValueError(f"{name} must be a positive integer; got {value!r}")
    return int(value)


class Linear(Module):
    """y = x W^T + b, with W of shape (out_features, in_features)."""

    def __init__(self, in_features: int, out_features: int, bias: bool = True, rng=None,
                 dtype=np.float32):
        rng = as_rng(rng)
        self.in_features = _positive("Linear in_features", in_features)
        self.out_features = _positive("Linear out_features", out_features)
        self.weight = Tensor(kaiming_uniform((out_features, in_features), in_features, rng,
                                             dtype), requires_grad=True)
        self.bias = (Tensor(uniform_fan_in((out_features,), in_features, rng, dtype),
                            requires_grad=True) if bias else None)

    def forward(self, x: Tensor) -> Tensor:
        if x.shape[-1] != self.in_features:
            raise ValueError(f"Linear: input's last axis must be {self.in_features}; got "
                             f"shape {x.shape}")
        y = ag.matmul(x, ag.transpose(self.weight))
        return y + self.bias if self.bias is not None else y


class Conv2d(Module):
    """2-D convolution over NCHW input; weight (out_channels, in_channels, KH, KW)."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size, stride=1,
                 padding=0, bias: bool = True, rng=None, dtype=np.float32):
        rng = as_rng(rng)
        kh, kw = (kernel_size, kernel_size) if np.isscalar(kernel_size) else kernel_size
        self.in_channels = _positive("Conv2d in_channels", in_channels)
        self.out_channels = _positive("Conv2d out_channels", out_channels)
        self.stride, self.padding = stride, padding
        fan_in = in_channels * kh * kw
        self.weight = Tensor(kaiming_uniform((out_channels, in_channels, kh, kw), fan_in,
                                             rng, dtype), requires_grad=True)
        self.bias = (Tensor(uniform_fan_in((out_channels,), fan_in, rng, dtype),
                            requires_grad=True) if bias else None)

    def forward(self, x: Tensor) -> Tensor:
        return ag.conv2d(x, self.weight, self.bias, self.stride, self.padding)


class LSTM(Module):
    """One LSTM layer over a sequence (T, B, input_size) -> (T, B, hidden_size).

    Gates in PyTorch's order (input, forget, cell, output); one bias of size 4H.
    The forget-gate bias starts at 1, a common choice that helps memory early on.
    """

    def __init__(self, input_size: int, hidden_size: int, rng=None, dtype=np.float32):
        rng = as_rng(rng)
        self.input_size = _positive("LSTM input_size", input_size)
        self.hidden_size = H = _positive("LSTM hidden_size", hidden_size)
        self.weight_ih = Tensor(uniform_fan_in((4 * H, input_size), H, rng, dtype),
                                requires_grad=True)
        self.weight_hh = Tensor(uniform_fan_in((4 * H, H), H, rng, dtype), requires_grad=True)
        bias = uniform_fan_in((4 * H,), H, rng, dtype)
        bias[H:2 * H] = 1.0
        self.bias = Tensor(bias, requires_grad=True)

    def initial_state(self, batch: int, dtype=None) -> tuple[Tensor, Tensor]:
        dtype = dtype or self.weight_ih.dtype
        zeros = np.zeros((batch, self.hidden_size), dtype=dtype)
        return Tensor(zeros), Tensor(zeros.copy())

    def forward(self, x: Tensor, state=None):
        """x: (T, B, I); state: (h0, c0) each (B, H) or None for zeros.

        Returns (outputs (T, B, H), (h_T, c_T)).
        """
        if x.ndim != 3 or x.shape[2] != self.input_size:
            raise ValueError(f"LSTM: input must have shape (T, B, {self.input_size}); got "
                             f"{x.shape}")
        h0, c0 = state if state is not None else self.initial_state(x.shape[1], x.dtype)
        return ag.lstm(x, h0, c0, self.weight_ih, self.weight_hh, self.bias)


class Sequential(Module):
    """Apply layers in order: Sequential(Conv2d(...), ReLU(), ...)."""

    def __init__(self, *layers: Module):
        for i, layer in enumerate(layers):
            if not isinstance(layer, Module):
                raise TypeError(f"Sequential: layer {i} must be a Module; got "
                                f"{type(layer).__name__}")
        self.layers = list(layers)

    def forward(self, x):
        for layer in self.layers:
            x = layer(x)
        return x

    def __getitem__(self, i):
        return self.layers[i]

    def __len__(self):
        return len(self.layers)


class ReLU(Module):
    def forward(self, x):
        return ag.relu(x)


class ELU(Module):
    def forward(self, x):
        return ag.elu(x)


class Tanh(Module):
    def forward(self, x):
        return ag.tanh(x)


class Flatten(Module):
    """(N, ...) -> (N, prod(...))."""

    def forward(self, x):
        return ag.flatten(x, 1)


# -- graph-free inference ---------------------------------------------------------------
class ConvInference:
    """A convolution's weights frozen for inference: channels-last arrays in and out, no
    autograd graph. ``ConvInference(conv2d_layer)`` or ``ConvInference.of(weight, bias,
    stride, padding)``; call it, or ``bind`` it to fixed buffers.

    Why it exists: ``ag.conv2d`` checks its arguments, lays the weight out as a matrix,
    wraps the result in a Tensor and keeps a closure for the backward pass, on every
    call. Training needs the backward pass; inference (the DispNet in the flight loop,
    one frame at a time) does not, and at batch 1 that bookkeeping plus the NCHW <->
    channels-last copies cost as much as the arithmetic. This object does the weight
    layout once and then runs what ``ag.conv2d``'s forward runs,
    ``autograd.conv.conv2d_nhwc`` (im2col + GEMM, through its ``conv2d_nhwc_plan``), so
    the two paths share one implementation of the convolution and give the same
    numbers, to the last bit.

    One exception, for layers with very few output channels (KH*KW*C_out <= C_in, stride
    1: a disparity head, C_out = 1): im2col would copy KH*KW values per input value
    for a GEMM that does almost nothing with them. There the channels are contracted
    first, ``P[t] = xp @ w[:, :, t]`` for each kernel tap t (one small GEMM, no copy),
    and the output is the sum of the KH*KW tap images shifted by their offsets. Same
    products, summed in another order: equal to float round-off, not to the bit.

    It is a *snapshot*: later changes to the layer's weights (an optimizer step,
    ``load_state_dict``) are not seen; build a new one.

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
        (no bias), with every strided view prepared now: for buffers that are reused
        call after call (``DispNetInference``), where re-deriving the views each time
        would cost more than the arithmetic of the small layers at batch 1."""
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

    ``ag.elu`` (training) computes ``where(x > 0, x, expm1(min(x, 0)))``. Here ``expm1``
    is replaced by ``exp(.) - 1``, for speed: NumPy runs ``exp`` with SIMD instructions
    on any x86-64 CPU of the last decade, but ``expm1`` only where AVX-512 is present
    (through Intel's SVML); elsewhere it calls the C library once per element. On an
    AVX2 machine (AMD EPYC, twenty-ninth session) that is 11.0 ns against 1.9 ns per
    float32, and this function was more than half of the DispNet's inference time
    (``python benchmarks/bench_dispnet_chunk.py --elu``).

    What that costs in accuracy: for x > 0 nothing (the second term is exactly 0, so
    y = x to the bit, as in ``ag.elu``). For x <= 0, ``exp(x)`` lies in (0, 1] and
    ``exp(x) - 1`` is computed exactly when exp(x) >= 1/2 (Sterbenz), so the error is
    ``exp``'s rounding, at most about one unit in the last place of 1.0 (1.2e-7 in
    float32) in absolute terms; ``expm1`` would be accurate relative to the (tiny)
    result near 0, which a network does not need. The DispNet's disparity moves by
    about 1e-6 relative (tests/test_fast_inference.py bounds it), the order of the
    round-off this inference path already differs by (the module docstring of
    ``nets.dispnet``).

    No ``np.where`` (slow) and no allocation: ``scratch`` and ``zeros`` are arrays of
    ``y``'s shape and dtype (``zeros`` all zeros: NumPy's SIMD min/max loops want two
    contiguous operands; a scalar 0 is ~2.5x slower).
    """
    if bias is not None:
        y += bias
    np.minimum(y, zeros, out=scratch)
    np.maximum(y, zeros, out=y)
    np.exp(scratch, out=scratch)
    scratch -= y.dtype.type(1)          # exact for exp(x) in [1/2, 1]; 0 where x >= 0
    y += scratch
    return y
