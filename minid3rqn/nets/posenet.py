"""PoseNet: a target frame and its source frames -> one 6-DoF relative pose per source.

As in SfMLearner (Zhou et al. 2017): the frames are stacked on the channel axis,
(N, 3 (1 + S), H, W), and pass through strided 3x3 convolutions (each halves the
resolution) with ReLU; a 1x1 convolution gives 6 S channels, averaged over the image:

    pose_s = pose_scale * mean_{u,v} conv(features)[6 s : 6 s + 6]

The six numbers are (tx, ty, tz, rx, ry, rz): the transform T_{t->s} that maps
target-camera points into source s's camera (``depth.geometry.pose_vec_to_mat``).
A small ``pose_scale`` (SfMLearner: 0.01) keeps the first poses near the identity, so
early warps read the right neighbourhood and the depth can start to learn.
"""
from __future__ import annotations

import numpy as np

from .. import autograd as ag
from ..autograd import Tensor
from .init import as_rng
from .module import Module
from .dispnet import RGB_MEAN, RGB_STD
from .layers import Conv2d


class PoseNet(Module):
    """Args: n_sources S; channels of the strided convs; pose_scale; head_gain (the 1x1
    head's initial weights are multiplied by it, so the first poses are near 0);
    init_tz: optional forward translation per source the head starts at (its bias),
    e.g. (0.8, -0.8) for (previous, next) of a camera flying forward 0.8 m per frame;
    rng."""

    def __init__(self, n_sources: int = 2, channels=(16, 32, 64, 128, 128),
                 pose_scale: float = 0.01, head_gain: float = 1.0, init_tz=None, rng=0,
                 dtype=np.float32):
        rng = as_rng(rng)
        if n_sources < 1:
            raise ValueError(f"PoseNet: n_sources must be >= 1; got {n_sources}")
        self.n_sources, self.channels, self.pose_scale = n_sources, tuple(channels), pose_scale
        self.convs, c_in = [], 3 * (1 + n_sources)
        for c in channels:
            self.convs.append(Conv2d(c_in, c, 3, stride=2, padding=1, rng=rng, dtype=dtype))
            c_in = c
        self.head = Conv2d(c_in, 6 * n_sources, 1, rng=rng, dtype=dtype)
        self.head.weight.data *= head_gain
        self.head.bias.data *= head_gain
        if init_tz is not None:
            if len(init_tz) != n_sources:
                raise ValueError(f"PoseNet: init_tz needs one value per source; got {init_tz}")
            for k, value in enumerate(init_tz):
                self.head.bias.data[6 * k + 2] = value / pose_scale     # tz of source k

    def forward(self, target, sources) -> Tensor:
        """target (N, 3, H, W), sources: list of S arrays (N, 3, H, W), RGB in [0, 1].

        Returns (N, S, 6) pose vectors T_{t->s}.
        """
        frames = [target] + list(sources)
        if len(frames) != 1 + self.n_sources:
            raise ValueError(f"PoseNet: expected {self.n_sources} sources; got "
                             f"{len(frames) - 1}")
        frames = [f if isinstance(f, Tensor) else Tensor(np.asarray(f)) for f in frames]
        shapes = {f.shape for f in frames}
        if len(shapes) != 1 or frames[0].ndim != 4 or frames[0].shape[1] != 3:
            raise ValueError(f"PoseNet: target and sources must all be (N, 3, H, W); got "
                             f"{[f.shape for f in frames]}")
        x = (ag.concat(frames, axis=1) - RGB_MEAN) * (1.0 / RGB_STD)
        for conv in self.convs:
            x = ag.relu(conv(x))
        x = ag.mean(self.head(x), axis=(2, 3))                        # (N, 6 S)
        scale = np.full(6, self.pose_scale, dtype=x.dtype)
        return ag.reshape(x, (x.shape[0], self.n_sources, 6)) * scale
