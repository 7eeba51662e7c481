"""DispNet: one RGB frame -> disparity (inverse depth) at several scales.

An encoder-decoder with skip connections, the shape of SfMLearner's DispNet (Zhou et
al. 2017) and monodepth2's decoder (Godard et al. 2019), shrunk to 32x104 images:

    encoder   level i (i = 0..L-1): conv 3x3 stride 2 + ELU, conv 3x3 + ELU
              32x104 -> 16x52 -> 8x26 -> 4x13 -> 2x7
    decoder   level i (i = L-1..0): conv 3x3 + ELU, nearest upsample x2, crop to the
              skip's size, concat the encoder's level i-1 features, conv 3x3 + ELU
    heads     at decoder levels i < n_scales: disp_i = a * sigmoid(conv 3x3) + b
              (SfMLearner: a = 10, b = 0.01, so depth = 1 / disp lies in (0.1, 100))

Scale i has resolution (H / 2^i, W / 2^i); ``forward`` returns the list finest first.
Input: float RGB in [0, 1], (N, 3, H, W); it is normalised inside ((x - 0.45) / 0.225).
ELU rather than ReLU everywhere: its gradient never dies, which matters with few
iterations (monodepth2 uses ELU in its decoder for the same reason).
"""
from __future__ import annotations

import numpy as np

from .. import autograd as ag
from ..autograd import Tensor
from .init import as_rng
from .layers import Conv2d
from .module import Module


RGB_MEAN, RGB_STD = 0.45, 0.225


def _crop_to(x: Tensor, h: int, w: int) -> Tensor:
    """x[..., :h, :w]; upsampling odd sizes (2x7 -> 4x14) overshoots by one."""
    if x.shape[2] == h and x.shape[3] == w:
        return x
    return x[:, :, :h, :w]


class DispNet(Module):
    """Encoder-decoder from RGB to multi-scale disparity (see the module docstring).

    Args:
        encoder: channels of the encoder levels (each halves the resolution).
        decoder: channels of the decoder levels, same length, finest first.
        n_scales: disparity outputs at decoder levels 0..n_scales-1.
        disp_scale, min_disp: a and b in disp = a sigmoid(z) + b.
        init_disp: the disparity every head starts near (its bias is set to
            logit((init_disp - b) / a)); None keeps the default init (disp ~ a/2 + b).
        rng: seed or np.random.Generator for the initial weights.
    """

    def __init__(self, encoder=(16, 32, 64, 96), decoder=(16, 16, 32, 64), n_scales: int = 4,
                 disp_scale: float = 10.0, min_disp: float = 0.01,
                 init_disp: float | None = 0.1, rng=0, dtype=np.float32):
        rng = as_rng(rng)
        if len(encoder) != len(decoder):
            raise ValueError(f"DispNet: encoder and decoder need one entry per level; got "
                             f"{len(encoder)} and {len(decoder)}")
        if not 1 <= n_scales <= len(encoder):
            raise ValueError(f"DispNet: n_scales must be in [1, {len(encoder)}]; got {n_scales}")
        self.encoder_channels, self.decoder_channels = tuple(encoder), tuple(decoder)
        self.n_scales, self.disp_scale, self.min_disp = n_scales, disp_scale, min_disp
        self.enc_a, self.enc_b, c_in = [], [], 3
        for c in encoder:
            self.enc_a.append(Conv2d(c_in, c, 3, stride=2, padding=1, rng=rng, dtype=dtype))
            self.enc_b.append(Conv2d(c, c, 3, stride=1, padding=1, rng=rng, dtype=dtype))
            c_in = c
        self.dec_a, self.dec_b, self.heads = [], [], []
        levels = len(encoder)
        for i in reversed(range(levels)):
            self.dec_a.append(Conv2d(c_in, decoder[i], 3, padding=1, rng=rng, dtype=dtype))
            skip = encoder[i - 1] if i > 0 else 0
            self.dec_b.append(Conv2d(decoder[i] + skip, decoder[i], 3, padding=1, rng=rng,
                                     dtype=dtype))
            c_in = decoder[i]
        for i in range(n_scales):
            self.heads.append(Conv2d(decoder[i], 1, 3, padding=1, rng=rng, dtype=dtype))
        if init_disp is not None:
            # Start far (0.1: 10 m, beyond the scenes' depth) rather than at a/2 + b (0.2 m):
            # a depth guessed too near makes every warp worse than none, a guess too far
            # gets pulled nearer (docs/depth.md, section 5).
            q = (init_disp - min_disp) / disp_scale
            for head in self.heads:
                head.bias.set_(np.log(q / (1 - q)))

    def config(self) -> dict:
        return {"encoder": list(self.encoder_channels), "decoder": list(self.decoder_channels),
                "n_scales": self.n_scales, "disp_scale": self.disp_scale,
                "min_disp": self.min_disp}

    def forward(self, rgb, scales: int | None = None) -> list[Tensor]:
        """rgb (N, 3, H, W) float in [0, 1] -> [disp_0 (N,1,H,W), disp_1 (N,1,H/2,W/2), ...].

        ``scales``: compute only the finest ``scales`` heads (1 for inference).
        """
        x = rgb if isinstance(rgb, Tensor) else Tensor(np.asarray(rgb))
        if x.ndim != 4 or x.shape[1] != 3:
            raise ValueError(f"DispNet: input must be (N, 3, H, W) RGB; got shape {x.shape}")
        h, w = x.shape[2:]
        x = (x - RGB_MEAN) * (1.0 / RGB_STD)
        feats = []
        for conv_a, conv_b in zip(self.enc_a, self.enc_b):
            x = ag.elu(conv_a(x))
            x = ag.elu(conv_b(x))
            feats.append(x)
        levels = len(self.enc_a)
        n_out = self.n_scales if scales is None else max(1, min(int(scales), self.n_scales))
        disps = [None] * self.n_scales
        for j, i in enumerate(reversed(range(levels))):
            x = ag.elu(self.dec_a[j](x))
            x = ag.upsample(x, 2, "nearest")
            th, tw = -(-h // 2 ** i), -(-w // 2 ** i)          # ceil(h / 2^i)
            x = _crop_to(x, th, tw)
            if i > 0:
                x = ag.concat([x, feats[i - 1]], axis=1)
            x = ag.elu(self.dec_b[j](x))
            if i < n_out:
                disps[i] = ag.sigmoid(self.heads[i](x)) * self.disp_scale + self.min_disp
        return disps[:n_out]
