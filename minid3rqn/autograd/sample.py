"""Bilinear sampling of images at real-valued pixel coordinates: the view-synthesis warp.

Convention (shared with ``minid3rqn.world.geometry.inverse_warp_numpy``):

- ``coords[n, v, u] = (x, y)`` says where output pixel (v, u) reads image n: ``x`` is the
  column (horizontal, grows rightwards), ``y`` the row (vertical, grows downwards), both
  in PIXEL units.
- Pixel centres sit at integer coordinates: ``(0, 0)`` is the centre of the top-left
  pixel, ``(W-1, H-1)`` the centre of the bottom-right one. So the identity grid
  ``coords[n, v, u] = (u, v)`` reproduces the image, and a grid shifted by +1 in x reads
  each pixel's right-hand neighbour.
- This equals ``torch.nn.functional.grid_sample(image, grid, align_corners=True)`` with
  ``grid = 2 * coords / (size - 1) - 1`` (per axis: x with W, y with H).

The interpolation. With x0 = floor(x), x1 = x0 + 1, wx = x - x0 (and likewise y)::

    out = (1-wx)(1-wy) I00 + wx(1-wy) I01 + (1-wx) wy I10 + wx wy I11,
    I_ab = image[y0 + a, x0 + b]   (a: row offset, b: column offset)

Out-of-view handling (``padding_mode``):

- "zeros": a corner outside the image reads 0, so the output fades to 0 within one
  pixel outside the image and is 0 beyond that.
- "border": x is clamped to [0, W-1] and y to [0, H-1] before interpolating, so points
  outside read the nearest edge value. Where a coordinate is clamped its gradient is 0
  (as in torch, which also gives 0 exactly on the edge).

Gradients (per channel, then summed over channels against the incoming ``g``)::

    dout/dx = (1-wy)(I01 - I00) + wy (I11 - I10)
    dout/dy = (1-wx)(I10 - I00) + wx (I11 - I01)
    dL/dimage[n, c, y0+a, x0+b] += g[n, c, v, u] * w_ab      (scatter, via np.bincount)

Bilinear interpolation is continuous but not differentiable where x or y is an integer
(the corner set changes); the gradient there is the right-hand one (x0 = x, wx = 0).
"""
from __future__ import annotations

import numpy as np

from .engine import Tensor, check_same_dtype, float_tensor

PADDING_MODES = ("zeros", "border")


def bilinear_sample(image, coords, padding_mode: str = "zeros") -> tuple[Tensor, np.ndarray]:
    """Sample ``image`` at real-valued pixel coordinates, bilinearly.

    Args:
        image: (N, C, H, W) Tensor or array.
        coords: (N, Ho, Wo, 2) pixel coordinates (x = column, y = row; pixel centres at
            integers, see the module docstring). Same float dtype as ``image``.
        padding_mode: "zeros" or "border" (module docstring).

    Returns:
        (out, valid): out is an (N, C, Ho, Wo) Tensor, differentiable with respect to
        both ``image`` and ``coords``; valid is an (N, 1, Ho, Wo) NumPy array (no
        gradient), 1.0 where 0 <= x <= W-1 and 0 <= y <= H-1, else 0.0.

    How it is computed: the image is framed by one pixel of zeros, so every corner
    index is in range and no corner needs masking. x is clamped to [lo, hi] with
    (lo, hi) = (-1, W) for "zeros" (from there on outwards the output is 0, so clamping
    changes no value) and (0, W-1) for "border"; the gradient is 0 where clamped.
    Then x0 = min(floor(x), hi - 1) (so x1 = x0 + 1 <= hi stays in the frame; at x = hi
    this gives wx = 1, the same value). The same for y. One (4, N, P) array of flat
    indices (corners 00, 01, 10, 11 of every point, P = Ho*Wo) serves every channel: the
    forward gathers with one ``np.take`` from the (C, N*(H+2)*(W+2)) channel planes, the
    backward scatters with one ``np.bincount`` per channel.
    """
    image, coords = _check_inputs(image, coords, padding_mode)
    n, ch, height, width = image.shape
    _, ho, wo, _ = coords.shape
    dtype = image.dtype
    points = ho * wo
    x = coords.data[..., 0].reshape(n, points)
    y = coords.data[..., 1].reshape(n, points)
    if np.isnan(x).any() or np.isnan(y).any():
        raise ValueError("bilinear_sample: coords contain NaN (a diverged depth or pose?)")
    valid = ((x >= 0) & (x <= width - 1) & (y >= 0) & (y <= height - 1))
    valid = valid.astype(dtype).reshape(n, 1, ho, wo)

    pad = 1 if padding_mode == "zeros" else 0            # how far outside we interpolate
    lo_x, hi_x, lo_y, hi_y = -pad, width - 1 + pad, -pad, height - 1 + pad
    slope_x = ((x > lo_x) & (x < hi_x)).astype(dtype)     # d(clamped x)/dx: 0 where clamped
    slope_y = ((y > lo_y) & (y < hi_y)).astype(dtype)
    x, y = np.clip(x, lo_x, hi_x), np.clip(y, lo_y, hi_y)
    x0 = np.minimum(np.floor(x), hi_x - 1)
    y0 = np.minimum(np.floor(y), hi_y - 1)
    wx, wy = x - x0, y - y0                                 # weights of x1 and y1
    weights = np.stack([(1 - wy) * (1 - wx), (1 - wy) * wx,  # w00, w01, w10, w11 (4, N, P)
                        wy * (1 - wx), wy * wx])

    fh, fw = height + 2, width + 2                          # the framed image
    framed = np.zeros((ch, n, fh, fw), dtype)
    framed[:, :, 1:-1, 1:-1] = image.data.transpose(1, 0, 2, 3)
    planes = framed.reshape(ch, n * fh * fw)
    corner00 = ((np.arange(n) * (fh * fw))[:, None] + (y0.astype(np.int64) + 1) * fw
                + (x0.astype(np.int64) + 1))                                    # (N, P)
    index = corner00 + np.array([0, 1, fw, fw + 1])[:, None, None]              # (4, N, P)
    values = np.take(planes, index, axis=1)                 # I_00, I_01, I_10, I_11: (C, 4, N, P)
    out = np.einsum("knp,cknp->ncp", weights, values).reshape(n, ch, ho, wo)

    def vjp(g):
        g = g.reshape(n, ch, points)
        grad_image = grad_coords = None
        if image.requires_grad:
            flat_index = index.reshape(-1)
            grad_framed = np.empty((ch, n, fh, fw), dtype)
            for c in range(ch):
                grad_framed[c] = np.bincount(flat_index, weights=(weights * g[:, c]).reshape(-1),
                                             minlength=planes.shape[1]).reshape(n, fh, fw)
            grad_image = grad_framed[:, :, 1:-1, 1:-1].transpose(1, 0, 2, 3)
        if coords.requires_grad:
            i00, i01, i10, i11 = values.transpose(1, 2, 0, 3)  # each (N, C, P)
            wx_, wy_ = wx[:, None, :], wy[:, None, :]
            dx = (1 - wy_) * (i01 - i00) + wy_ * (i11 - i10)
            dy = (1 - wx_) * (i10 - i00) + wx_ * (i11 - i01)
            gx = np.einsum("ncp,ncp->np", g, dx) * slope_x
            gy = np.einsum("ncp,ncp->np", g, dy) * slope_y
            grad_coords = np.stack([gx, gy], axis=-1).reshape(coords.shape)
        return grad_image, grad_coords

    return Tensor.from_op(out, (image, coords), vjp, "bilinear_sample"), valid


def _check_inputs(image, coords, padding_mode: str) -> tuple[Tensor, Tensor]:
    op = "bilinear_sample"
    if padding_mode not in PADDING_MODES:
        raise ValueError(f"{op}: padding_mode must be one of {PADDING_MODES}; "
                         f"got {padding_mode!r}")
    image, coords = float_tensor(image, "image", op), float_tensor(coords, "coords", op)
    if image.ndim != 4:
        raise ValueError(f"{op}: image must be 4-D (N, C, H, W); got shape {image.shape}")
    if coords.ndim != 4 or coords.shape[-1] != 2:
        raise ValueError(f"{op}: coords must be 4-D (N, Ho, Wo, 2) with (x, y) pixel "
                         f"coordinates last; got shape {coords.shape}")
    if coords.shape[0] != image.shape[0]:
        raise ValueError(f"{op}: coords and image must have the same batch size N; got "
                         f"coords {coords.shape} and image {image.shape}")
    if image.shape[2] < 1 or image.shape[3] < 1:
        raise ValueError(f"{op}: image must have H, W >= 1; got shape {image.shape}")
    check_same_dtype((image, coords), op)
    return image, coords
