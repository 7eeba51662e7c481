"""Networks: the Module base, layers, and (in their own files) DispNet, PoseNet, QNet."""
from .module import Module
from .layers import Linear, Conv2d, LSTM, Sequential, Tanh
from .init import as_rng, uniform_fan_in, kaiming_uniform
