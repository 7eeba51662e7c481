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

Two ways to run it. ``DispNet.forward`` builds the autograd graph: training uses it
(and so does anything that needs gradients). ``DispNetInference`` (``net.inference()``)
evaluates a frozen copy of the weights at the finest scale only, with plain NumPy on
channels-last arrays and preallocated buffers, calling the same convolution routine
(``autograd.conv.conv2d_nhwc``); it exists because the flight loop runs the DispNet
once per frame, and at batch 1 the graph bookkeeping cost as much as the arithmetic.
Its output equals ``forward(x, scales=1)[0]`` (tests/test_fast_inference.py).
"""
from __future__ import annotations

import numpy as np

from .. import autograd as ag
from ..autograd import Tensor
from .init import as_rng
from ..autograd.elementwise import _stable_sigmoid
from .layers import Conv2d, ConvInference, bias_elu_, upsample_conv_phases
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
        double_conv: two convs per encoder level (True) or one.
        init_disp: the disparity every head starts near (its bias is set to
            logit((init_disp - b) / a)); None keeps the default init (disp ~ a/2 + b).
        rng: seed or np.random.Generator for the initial weights.
    """

    def __init__(self, encoder=(16, 32, 64, 96), decoder=(16, 16, 32, 64), n_scales: int = 4,
                 disp_scale: float = 10.0, min_disp: float = 0.01, double_conv: bool = True,
                 init_disp: float | None = 0.5, rng=0, dtype=np.float32):
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
            if double_conv:
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
            # Start in the log-middle of the range [b, a + b] instead of at a/2 + b (near
            # its top), so near and far surfaces both fit inside the range as the scale
            # settles (docs/depth.md, "choices").
            q = (init_disp - min_disp) / disp_scale
            for head in self.heads:
                head.bias.data[...] = np.log(q / (1 - q))

    def config(self) -> dict:
        return {"encoder": list(self.encoder_channels), "decoder": list(self.decoder_channels),
                "n_scales": self.n_scales, "disp_scale": self.disp_scale,
                "min_disp": self.min_disp, "double_conv": bool(self.enc_b)}

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
        for i, conv in enumerate(self.enc_a):
            x = ag.elu(conv(x))
            if self.enc_b:
                x = ag.elu(self.enc_b[i](x))
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

    def inference(self, chunk: int = 8) -> "DispNetInference":
        """A graph-free, finest-scale-only evaluator of the current weights (a snapshot)."""
        return DispNetInference(self, chunk)


class DispNetInference:
    """``DispNet.forward(x, scales=1)[0]`` without autograd: a snapshot for inference.

    Why: training needs the graph (``DispNet.forward``); inference does not, and in the
    flight loop (one frame per step, batch 1) the per-op overhead of the graph (Tensor
    wrappers, argument checks, the weights re-laid out as matrices on every call,
    NCHW <-> channels-last copies, ``np.where`` in ELU) was as large as the arithmetic.
    This class does the same computation with the same convolution routine
    (``ConvInference`` -> ``autograd.conv.conv2d_nhwc``), but

    - keeps activations channels-last (N, H, W, C) from input to output;
    - writes each layer's result straight into the zero-padded input buffer of the
      layer that reads it (in the decoder: upsampled into the first channels, the
      encoder's skip features into the last ones, so "upsample, crop, concat, pad" is
      a few strided copies); the buffers are allocated once per batch size;
    - applies bias + ELU in place (``bias_elu_``), with ``exp(x) - 1`` for the
      negative side where ``ag.elu`` has ``expm1(x)``: NumPy vectorizes ``exp`` on
      every x86-64 CPU but ``expm1`` only with AVX-512, and without it the ELU cost more
      than all the convolutions (on an AMD EPYC: 3.62 ms a frame, 1.53 without the
      ELU; ``benchmarks/bench_dispnet_chunk.py --elu``);
    - computes only the finest disparity head, the one inference uses;
    - at a decoder level without skip features and without cropping (the finest one,
      the largest layer), runs "upsample x2, conv 3x3" as four 2x2 convolutions of
      the small image (``upsample_conv_phases``: 4/9 of the work), and the 1-channel
      head by contracting channels first (``ConvInference``).

    The last two sum the same products in another order, and the ELU rounds its
    negative side differently (by at most about 1.2e-7 in float32), so the output
    equals ``forward`` to float round-off (about 1e-6 relative in float32), not to the
    bit; everything else is the same arithmetic in the same order.

    Large batches run ``chunk`` frames at a time, so that the working set (about
    1 MB of buffers per frame at 32x104) stays in the CPU caches; a batch gains
    little over single frames anyway (the GEMMs are already efficient at batch 1).
    How little: chunks of 2 to 64 frames run within 3% of each other on a 16 MB-L3
    AMD EPYC (``benchmarks/bench_dispnet_chunk.py``); the chunk changes the last bit of
    some outputs (the GEMMs' row counts change), so the default stays 8.

    A snapshot: weights changed after construction (training) are not seen; build a
    new one with ``net.inference()``. Not thread-safe (the buffers are shared): one
    instance per thread.
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

        x = first = padded(h, w, self.enc_a[0].in_channels)
        enc = []
        for lvl, conv_a in enumerate(self.enc_a):
            level = {}
            y = conv(level, "a", conv_a, x)
            if self.enc_b:
                level["xb"] = padded(*y.shape[1:])
                y = conv(level, "b", self.enc_b[lvl], level["xb"])
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
        disparity (N, H, W) at the finest scale (the network's dtype). A two-frame
        DispNet reads (N, H, W, 6): the frame's channels, then the previous frame's; a
        DispNet with a cost volume reads its D planes after them (float input)."""
        rgb = np.asarray(rgb)
        c = self.enc_a[0].in_channels
        if rgb.ndim != 4 or rgb.shape[-1] != c:
            raise ValueError(f"DispNetInference: rgb must be (N, H, W, {c}); got {rgb.shape}")
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
            y = level["a"]()
            if "b" in level:
                level["xb"][:, 1:-1, 1:-1] = y
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


__all__ = ["DispNet", "DispNetInference"]
