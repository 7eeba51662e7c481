"""QNet: one builder for the paper's four Q-networks (DDQN, D3QN, DDRQN, D3RQN).

All four use double Q-learning (that lives in the update rule, ``rl/agent.py``); the
network differs along two switches:

    recurrent  conv features -> LSTM(width)           (DRQN, Hausknecht & Stone 2015)
               or              FC(width) + ReLU       (a DQN torso of the same width)
    dueling    Q = V + A - mean_a A                   (Wang et al. 2016)
               or Q = FC(width -> n_actions)

The conv stack is the paper's Table 1 scaled to our 32x104 depth maps (the paper's
128x416 divided by 4 per side)::

    paper  128x416x1 -conv 8x8 s4 (4)-> 31x103 -conv 4x4 s2 (8)-> 14x50 -conv 3x3 s2 (8)-> 6x24
    ours    32x104xC -conv 4x4 s2 (4)-> 15x51  -conv 4x4 s2 (8)->  6x24 -conv 3x3 s1 (8)-> 4x22

The first layer's kernel and stride are halved (on an image a quarter as wide a 4x4
window spans 1/26 of the width, twice the paper's 8 of 416 pixels, 1/52); the second
layer is kept; after it our map is already the paper's
6x24 after three layers, so the third layer keeps the paper's 3x3 kernel with stride 1.
All valid (no) padding, ReLU after each conv. That is 8 x 4 x 22 = 704 features (the
paper's 1152), feeding an LSTM or FC of ``width`` units (default 128).

Shapes. Every forward takes a sequence: ``obs`` (T, B, C, H, W) -> Q (T, B, n_actions).
C is the number of stacked depth frames (1: last frame only; 5: the 5-frame window as
channels, for the non-recurrent variants). A non-recurrent net treats the T steps
independently; a recurrent one carries (h, c) through them and returns the new state.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .. import autograd as ag
from ..autograd import Tensor
from .init import as_rng
from .layers import LSTM, Conv2d, Linear
from .module import Module

# The four settings of the family (double Q always).
VARIANTS = {
    "ddqn": dict(dueling=False, recurrent=False),
    "d3qn": dict(dueling=True, recurrent=False),
    "ddrqn": dict(dueling=False, recurrent=True),
    "d3rqn": dict(dueling=True, recurrent=True),
}


def conv_out(size: int, kernel: int, stride: int) -> int:
    """Output length of a valid convolution: floor((size - kernel) / stride) + 1."""
    return (size - kernel) // stride + 1


@dataclass
class QNetConfig:
    """Everything that fixes a QNet's architecture (saved with its weights)."""
    dueling: bool = True
    recurrent: bool = True
    in_channels: int = 1            # stacked frames per step (1, or 5 for a stacked window)
    height: int = 32                # ours: the paper's 128 / 4
    width_px: int = 104             # ours: the paper's 416 / 4
    n_actions: int = 5              # paper, Table 3
    # (out_channels, kernel, stride) per conv layer; ours, scaled from Table 1 (see top)
    convs: list = field(default_factory=lambda: [[4, 4, 2], [8, 4, 2], [8, 3, 1]])
    width: int = 128                # LSTM / FC units (ours; the paper does not give it)

    @classmethod
    def for_variant(cls, variant: str, **overrides) -> "QNetConfig":
        key = variant.lower()
        if key not in VARIANTS:
            raise ValueError(f"QNetConfig.for_variant: variant must be one of "
                             f"{sorted(VARIANTS)}; got {variant!r}")
        return cls(**{**VARIANTS[key], **overrides})

    def feature_shape(self) -> tuple[int, int, int]:
        """(channels, rows, cols) after the conv stack; raises if a layer does not fit."""
        h, w, c = self.height, self.width_px, self.in_channels
        for i, (out, k, s) in enumerate(self.convs):
            h2, w2 = conv_out(h, k, s), conv_out(w, k, s)
            if h2 < 1 or w2 < 1:
                raise ValueError(f"QNetConfig: conv layer {i} ({k}x{k} stride {s}) does not fit "
                                 f"its {h}x{w} input; reduce the kernel or the stride")
            h, w, c = h2, w2, out
        return c, h, w

    def to_dict(self) -> dict:
        return asdict(self)


class QNet(Module):
    """Conv torso, LSTM or FC core, dueling or plain head. See the module docstring."""

    def __init__(self, config: QNetConfig | None = None, rng=None):
        rng = as_rng(rng)
        self.config = cfg = config or QNetConfig()
        if cfg.in_channels < 1 or cfg.n_actions < 1 or cfg.width < 1:
            raise ValueError(f"QNet: in_channels, n_actions and width must be >= 1; got "
                             f"{cfg.in_channels}, {cfg.n_actions}, {cfg.width}")
        c = cfg.in_channels
        self.convs = []
        for out, k, s in cfg.convs:
            self.convs.append(Conv2d(c, int(out), int(k), stride=int(s), rng=rng))
            c = int(out)
        self.n_features = int(np.prod(cfg.feature_shape()))
        if cfg.recurrent:
            self.core = LSTM(self.n_features, cfg.width, rng=rng)
        else:
            self.core = Linear(self.n_features, cfg.width, rng=rng)
        if cfg.dueling:
            self.value = Linear(cfg.width, 1, rng=rng)
            self.advantage = Linear(cfg.width, cfg.n_actions, rng=rng)
        else:
            self.q_head = Linear(cfg.width, cfg.n_actions, rng=rng)

    @property
    def recurrent(self) -> bool:
        return self.config.recurrent

    def initial_state(self, batch: int):
        """Zero (h, c) of shape (batch, width) each; ``None`` for non-recurrent nets."""
        return self.core.initial_state(batch) if self.recurrent else None

    def features(self, obs: Tensor) -> Tensor:
        """(N, C, H, W) depth frames -> (N, n_features) conv features."""
        x = obs
        for conv in self.convs:
            x = ag.relu(conv(x))
        return ag.flatten(x, 1)

    def head(self, z: Tensor) -> Tensor:
        """(..., width) -> Q (..., n_actions); dueling: V + A - mean(A)."""
        if not self.config.dueling:
            return self.q_head(z)
        value = self.value(z)
        adv = self.advantage(z)
        return value + (adv - ag.mean(adv, axis=-1, keepdims=True))

    def forward(self, obs, state=None):
        """obs (T, B, C, H, W) -> (Q (T, B, n_actions), new state or None).

        ``state`` is (h, c) for recurrent nets (``None``: zeros); ignored otherwise.
        """
        obs = ag.as_tensor(obs) if not isinstance(obs, Tensor) else obs
        cfg = self.config
        expected = (cfg.in_channels, cfg.height, cfg.width_px)
        if obs.ndim != 5 or tuple(obs.shape[2:]) != expected:
            raise ValueError(f"QNet: obs must have shape (T, B, {expected[0]}, {expected[1]}, "
                             f"{expected[2]}); got {obs.shape}")
        T, B = obs.shape[:2]
        z = self.features(ag.reshape(obs, (T * B,) + expected))
        z = ag.reshape(z, (T, B, self.n_features))
        if self.recurrent:
            z, state = self.core(z, state)
        else:
            z, state = ag.relu(self.core(z)), None
        return self.head(z), state

    def step(self, obs, state=None):
        """One time step: obs (B, C, H, W) -> (Q (B, n_actions), new state); ``forward``
        on a sequence of length 1."""
        obs = obs.data if isinstance(obs, Tensor) else np.asarray(obs)
        q, state = self.forward(obs[None], state)
        return q[0], state


def variant_name(config: QNetConfig) -> str:
    for name, flags in VARIANTS.items():
        if flags == dict(dueling=config.dueling, recurrent=config.recurrent):
            return name
    raise AssertionError("unreachable")
