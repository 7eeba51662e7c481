"""PoseNet: a target frame and its source frames -> one 6-DoF relative pose per source.

As in SfMLearner (Zhou et al. 2017): the frames are stacked on the channel axis,
(N, 3 (1 + S), H, W), and pass through strided 3x3 convolutions (each halves the
resolution) with ReLU; a 1x1 convolution gives 6 S channels, averaged over the image:

    pose_s = scale * mean_{u,v} conv(features)[6 s : 6 s + 6]

(``pose_scale`` for the translation, ``rot_scale`` for the rotation.)

The six numbers are (tx, ty, tz, rx, ry, rz): the transform T_{t->s} that maps
target-camera points into source s's camera (``depth.geometry.pose_vec_to_mat``).

``dof=3`` is the planar variant for a drone at fixed altitude: the head predicts only
(tx, tz, ry) (sideways, forward, yaw about the camera's vertical y axis) and the other
three are 0. That is a prior about the platform (it never climbs, rolls or pitches),
not ground truth; the output keeps the 6-vector layout.
``pose_scale`` = 0.01 keeps the first poses near the identity, so early warps read
the right neighbourhood and the depth can start to learn.
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
    dof: 6 or 3 (planar); rng."""

    def __init__(self, n_sources: int = 2, channels=(16, 32, 64, 128, 128),
                 pose_scale: float = 0.01, head_gain: float = 1.0, dof: int = 6,
                 init_tz=None, rot_scale: float | None = None, rng=0, dtype=np.float32):
        rng = as_rng(rng)
        if n_sources < 1:
            raise ValueError(f"PoseNet: n_sources must be >= 1; got {n_sources}")
        if dof not in (3, 6):
            raise ValueError(f"PoseNet: dof must be 6 (full) or 3 (planar); got {dof}")
        self.n_sources, self.channels, self.pose_scale = n_sources, tuple(channels), pose_scale
        self.dof = dof
        self.rot_scale = pose_scale if rot_scale is None else rot_scale
        self.convs, c_in = [], 3 * (1 + n_sources)
        for c in channels:
            self.convs.append(Conv2d(c_in, c, 3, stride=2, padding=1, rng=rng, dtype=dtype))
            c_in = c
        self.head = Conv2d(c_in, dof * n_sources, 1, rng=rng, dtype=dtype)
        self.head.weight.data *= head_gain
        self.head.bias.data *= head_gain
        if init_tz is not None:
            if len(init_tz) != n_sources:
                raise ValueError(f"PoseNet: init_tz needs one value per source; got {init_tz}")
            tz = 2 if dof == 6 else 1                      # index of tz within a source
            for k, value in enumerate(init_tz):
                self.head.bias.data[k * dof + tz] = value / pose_scale

    def config(self) -> dict:
        return {"n_sources": self.n_sources, "channels": list(self.channels),
                "pose_scale": self.pose_scale, "rot_scale": self.rot_scale, "dof": self.dof}

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
        x = ag.mean(self.head(x), axis=(2, 3))                        # (N, dof S)
        # translation entries x pose_scale, rotation entries x rot_scale
        n_t = 3 if self.dof == 6 else 2
        scale = np.array([self.pose_scale] * n_t + [self.rot_scale] * (self.dof - n_t),
                         dtype=x.dtype)
        x = ag.reshape(x, (x.shape[0], self.n_sources, self.dof)) * scale
        if self.dof == 3:                         # (tx, tz, ry) -> (tx, 0, tz, 0, ry, 0)
            zero = Tensor(np.zeros(x.shape[:2] + (1,), dtype=x.dtype))
            a = slice(None)
            parts = [x[a, a, 0:1], zero, x[a, a, 1:2], zero, x[a, a, 2:3], zero]
            x = ag.concat(parts, axis=2)
        return x


__all__ = ["PoseNet"]
