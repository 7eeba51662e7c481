"""Layers: Linear, Conv2d, LSTM, Sequential and a parameter-free activation (Tanh).

Every layer takes ``rng`` (a seed or ``np.random.Generator``) for its initial weights,
so the same seed builds the same network.
"""
from __future__ import annotations

import numpy as np

from .. import autograd as ag
from ..autograd import Tensor
from ..autograd.conv import _int_pair
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
        # validated once, here: (h, w) pairs of ints
        self.stride = _int_pair(stride, "stride", "Conv2d", 1)
        self.padding = _int_pair(padding, "padding", "Conv2d", 0)
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
    """Apply layers in order: Sequential(Linear(...), Tanh(), ...)."""

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


class Tanh(Module):
    def forward(self, x):
        return ag.tanh(x)
