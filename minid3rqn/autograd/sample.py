"""Bilinear sampling of images at real-valued pixel coordinates: the view-synthesis warp.

Convention (shared with ``minid3rqn.world.geometry.inverse_warp_numpy``):

- ``coords[n, v, u] = (x, y)`` says where output pixel (v, u) reads image n: ``x`` is the
  column (horizontal, grows rightwards), ``y`` the row (vertical, grows downwards), both
  in PIXEL units.
- Pixel centres sit at integer coordinates: ``(0, 0)`` is the centre of the top-left
  pixel, ``(W-1, H-1)`` the centre of the bottom-right one. So ``pixel_grid(H, W)`` (the
  identity grid) reproduces the image, and a grid shifted by +1 in x reads each pixel's
  right-hand neighbour.
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

from .engine import FLOAT_DTYPES, Tensor, as_tensor, check_same_dtype

PADDING_MODES = ("zeros", "border")


def pixel_grid(height: int, width: int, dtype=np.float32) -> np.ndarray:
    """The identity sampling grid: (H, W, 2) with ``grid[v, u] = (u, v)`` = (x, y)."""
    if int(height) < 1 or int(width) < 1:
        raise ValueError(f"pixel_grid: height and width must be >= 1; got {height}, {width}")
    ys, xs = np.meshgrid(np.arange(height, dtype=dtype), np.arange(width, dtype=dtype),
                         indexing="ij")
    return np.stack([xs, ys], axis=-1)


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
    """
    image, coords = _check_inputs(image, coords, padding_mode)
    n, ch, height, width = image.shape
    _, ho, wo, _ = coords.shape
    dtype = image.dtype
    points = ho * wo
    x = coords.data[..., 0].reshape(n, points)
    y = coords.data[..., 1].reshape(n, points)
    valid = ((x >= 0) & (x <= width - 1) & (y >= 0) & (y <= height - 1))
    valid = valid.astype(dtype).reshape(n, 1, ho, wo)

    if padding_mode == "border":
        # d(clamped)/d(raw): 1 strictly inside, 0 where clamped (and on the edge, as torch)
        slope_x = ((x > 0) & (x < width - 1)).astype(dtype)
        slope_y = ((y > 0) & (y < height - 1)).astype(dtype)
        x = np.clip(x, 0, width - 1)
        y = np.clip(y, 0, height - 1)
    else:
        # Beyond one pixel outside every corner reads 0, so clamping to [-2, W+1] changes
        # neither the output nor the gradient; it keeps floor() of huge values in range.
        slope_x = slope_y = None
        x = np.clip(x, -2, width + 1)
        y = np.clip(y, -2, height + 1)

    x0f, y0f = np.floor(x), np.floor(y)
    wx, wy = (x - x0f).astype(dtype), (y - y0f).astype(dtype)      # weights of x1, y1
    x0, y0 = x0f.astype(np.int64), y0f.astype(np.int64)
    x1, y1 = x0 + 1, y0 + 1
    in_x0, in_x1 = (x0 >= 0) & (x0 < width), (x1 >= 0) & (x1 < width)
    in_y0, in_y1 = (y0 >= 0) & (y0 < height), (y1 >= 0) & (y1 < height)

    # Flat indices into image.ravel() for the four corners: ((n*C + c)*H + y)*W + x.
    # A corner outside the image points at index 0 with weight 0, so it reads and
    # receives nothing.
    base = (np.arange(n)[:, None, None] * ch + np.arange(ch)[None, :, None]) * (height * width)
    corners = []                               # (flat index (N, C, P), weight (N, P), inside)
    for yi, in_y, wy_ in ((y0, in_y0, 1 - wy), (y1, in_y1, wy)):
        for xi, in_x, wx_ in ((x0, in_x0, 1 - wx), (x1, in_x1, wx)):
            inside = in_y & in_x
            pix = np.where(inside, yi * width + xi, 0)
            corners.append((base + pix[:, None, :], wy_ * wx_ * inside, inside))

    flat_image = image.data.reshape(-1)
    values = [np.take(flat_image, idx) * inside[:, None, :]           # I_ab, (N, C, P)
              for idx, _, inside in corners]
    out = sum(w[:, None, :] * v for (_, w, _), v in zip(corners, values))
    out = out.astype(dtype, copy=False).reshape(n, ch, ho, wo)

    def vjp(g):
        g = g.reshape(n, ch, points)
        grad_image = grad_coords = None
        if image.requires_grad:
            index = np.concatenate([idx.reshape(-1) for idx, _, _ in corners])
            weights = np.concatenate([(g * w[:, None, :]).reshape(-1) for _, w, _ in corners])
            grad_image = np.bincount(index, weights=weights, minlength=flat_image.size)
            grad_image = grad_image.astype(dtype, copy=False).reshape(image.shape)
        if coords.requires_grad:
            i00, i01, i10, i11 = values
            dx = ((1 - wy)[:, None, :] * (i01 - i00) + wy[:, None, :] * (i11 - i10))
            dy = ((1 - wx)[:, None, :] * (i10 - i00) + wx[:, None, :] * (i11 - i01))
            gx, gy = (g * dx).sum(axis=1), (g * dy).sum(axis=1)           # (N, P)
            if slope_x is not None:
                gx, gy = gx * slope_x, gy * slope_y
            grad_coords = np.stack([gx, gy], axis=-1).astype(dtype, copy=False)
            grad_coords = grad_coords.reshape(coords.shape)
        return grad_image, grad_coords

    return Tensor.from_op(out, (image, coords), vjp, "bilinear_sample"), valid


def _check_inputs(image, coords, padding_mode: str) -> tuple[Tensor, Tensor]:
    op = "bilinear_sample"
    if padding_mode not in PADDING_MODES:
        raise ValueError(f"{op}: padding_mode must be one of {PADDING_MODES}; "
                         f"got {padding_mode!r}")
    for name, value in (("image", image), ("coords", coords)):
        if not isinstance(value, Tensor) and np.asarray(value).dtype not in FLOAT_DTYPES:
            raise TypeError(f"{op}: {name} must hold float32 or float64 values; got dtype "
                            f"{np.asarray(value).dtype}")
    image, coords = as_tensor(image), as_tensor(coords)
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


__all__ = ["bilinear_sample", "pixel_grid"]
