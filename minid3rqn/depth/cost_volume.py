"""A plane-sweep cost volume: depth read from motion, as an input to the DispNet (ours).

A single frame shows depth only through appearance (how big, how high, how hazy). Two
frames filmed 0.8 m apart show it through parallax: a near surface moves more in the
image than a far one. A plane sweep turns that into D numbers per pixel. For target
pixel p and each hypothesis depth d_k (k = 1..D), put the point at depth d_k on p's ray,
move it into the previous camera with the known motion and project it there:

    p'_k = proj(K T_{t->t-1} d_k K^-1 p)          (the warp of depth/geometry.py,
                                                   with the depth map set to d_k)
    cost_k(p) = |B_t(p) - B_{t-1}(p'_k)|,   B the brightness (mean of R, G, B) / 255

If d_k is the pixel's true depth, both frames see the same surface there and cost_k is
small; the depth whose cost is lowest is the motion's answer. The DispNet reads the D
costs next to the frame (``DispNet(cost_planes=D)``) and learns when to trust them: the
answer is sharp at the sides of the view and at edges, and weak straight ahead (a point
on the flight direction does not move in the image) and on plain surfaces. This is the
idea of multi-view stereo networks (MVSNet, Yao et al. 2018) and of ManyDepth (Watson
et al. 2021) for self-supervised depth, in its simplest form: no learned features, the
costs of raw brightness.

The motion is odometry, not a network's guess: the quadrotor flies at the commanded
2 m/s and turns at the commanded yaw rate (the gyro's), so T_{t->t-1} is known. In our
world it is exactly the arc flown, the relative transform of the two camera poses.
Nothing here is learned and no gradient flows through it: like the frame itself, the
cost volume is computed before the network (``plane_sweep_cost``, NumPy only).
"""
from __future__ import annotations

import numpy as np

from .geometry import Z_EPS, check_intrinsics, pixel_rays

NEAR, FAR = 0.5, 12.0          # m: the depths swept, from the safety distance to far
DEFAULT_PLANES = 12


def sweep_depths(n_planes: int = DEFAULT_PLANES, near: float = NEAR, far: float = FAR
                 ) -> np.ndarray:
    """The D hypothesis depths, nearest first, evenly spaced in inverse depth (parallax
    is proportional to 1 / depth, so equal steps in it are equal steps in the image)."""
    if isinstance(n_planes, bool) or not isinstance(n_planes, (int, np.integer)) \
            or n_planes < 2:
        raise ValueError(f"sweep_depths: n_planes must be an int >= 2; got {n_planes!r}")
    if not 0 < near < far:
        raise ValueError(f"sweep_depths: need 0 < near < far; got near={near}, far={far}")
    return 1.0 / np.linspace(1.0 / near, 1.0 / far, int(n_planes))


def plane_sweep_cost(frame, prev, T_to_prev, K, depths=None, chunk: int = 64
                     ) -> np.ndarray:
    """The cost volume of frames ``frame`` against the frames before them.

    Args:
        frame: (N, H, W, 3) uint8, the frames whose depth is wanted (targets).
        prev: (N, H, W, 3) uint8, the frame filmed one step before each.
        T_to_prev: (N, 4, 4), T_{t->t-1}: maps points in each target camera's frame to
            the previous camera's (``world.geometry.relative_transform(pose_t,
            pose_prev)``).
        K: (3, 3) intrinsics of these images.
        depths: the D hypothesis depths (default ``sweep_depths()``).
        chunk: frames warped at once (bounds the memory: chunk x D warps).

    Returns:
        (N, H, W, D) float32 in [0, 1]: for each pixel and depth d_k, the absolute
        difference of brightness (the mean of R, G, B, over 255) between the frame and
        the previous frame read, bilinearly, where depth d_k puts the pixel. Where that
        falls outside the previous image the coordinates are clamped to its border (as
        ``inverse_warp_numpy(..., padding="border")``), so every entry is a real
        difference. Brightness rather than colour: a third of the reads.
        ``examples/09_plane_sweep.py`` shows how good the depth of the lowest cost is on
        its own.

    The warp of ``depth.geometry.inverse_warp`` written out for D constant depth maps at
    once and without autograd: the flight loop computes it for every frame, so it has
    to cost about as much as the DispNet does, not ten times more.
    """
    frame, prev = np.asarray(frame), np.asarray(prev)
    for name, a in (("frame", frame), ("prev", prev)):
        if a.ndim != 4 or a.shape[-1] != 3 or a.dtype != np.uint8:
            raise ValueError(f"plane_sweep_cost: {name} must be uint8 (N, H, W, 3); got "
                             f"{a.dtype} {a.shape}")
    if prev.shape != frame.shape:
        raise ValueError(f"plane_sweep_cost: prev must have frame's shape {frame.shape}; "
                         f"got {prev.shape}")
    n, h, w, _ = frame.shape
    T = np.asarray(T_to_prev, dtype=np.float64)
    if T.shape != (n, 4, 4) or not np.isfinite(T).all():
        raise ValueError(f"plane_sweep_cost: T_to_prev must be finite (N, 4, 4) with N = {n}; "
                         f"got {T.shape}")
    depths = sweep_depths() if depths is None else np.asarray(depths, dtype=np.float64)
    if depths.ndim != 1 or len(depths) == 0 or not (depths > 0).all():
        raise ValueError(f"plane_sweep_cost: depths must be a 1-D array of positive depths; "
                         f"got {depths!r}")
    K = check_intrinsics(K, h, w, "plane_sweep_cost: K")
    d, hw = len(depths), h * w
    # K P_prev = (K R) (d_k r(p)) + K t = d_k (K R r(p)) + K t: one product per frame,
    # then a scale and a shift per plane.
    ray_image = (K @ T[:, :3, :3] @ pixel_rays(K, h, w, np.float64)).astype(np.float32)
    shift = (T[:, :3, 3] @ K.T).astype(np.float32)                         # (N, 3)
    planes = depths.astype(np.float32)[None, :, None, None]
    bright_prev = prev.mean(axis=-1, dtype=np.float32).reshape(n, hw)
    bright = frame.mean(axis=-1, dtype=np.float32).reshape(n, 1, hw)
    out = np.empty((n, h, w, d), np.float32)
    for k in range(0, n, max(1, int(chunk))):
        m = min(n, k + chunk) - k
        proj = planes * ray_image[k:k + m, None] + shift[k:k + m, None, :, None]  # (m,D,3,HW)
        inv_z = 1.0 / np.maximum(proj[:, :, 2], np.float32(Z_EPS))
        x = np.clip(proj[:, :, 0] * inv_z, 0, w - 1)                    # border padding
        y = np.clip(proj[:, :, 1] * inv_z, 0, h - 1)
        x0 = np.minimum(x.astype(np.int32), w - 2)        # x >= 0, so int() is floor()
        y0 = np.minimum(y.astype(np.int32), h - 2)
        ax, ay = x - x0, y - y0
        # The four neighbours as flat indices into this chunk's previous frames.
        i00 = y0 * w + x0 + (np.arange(m, dtype=np.int32) * hw)[:, None, None]
        table = bright_prev[k:k + m].ravel()
        top = _lerp(np.take(table, i00), np.take(table, i00 + 1), ax)
        bottom = _lerp(np.take(table, i00 + w), np.take(table, i00 + w + 1), ax)
        diff = np.abs(_lerp(top, bottom, ay) - bright[k:k + m])          # (m, D, HW)
        diff *= np.float32(1 / 255.0)
        out[k:k + m] = diff.transpose(0, 2, 1).reshape(m, h, w, d)
    return out


def _lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """a + (b - a) t: linear interpolation, t in [0, 1]."""
    b -= a
    b *= t
    b += a
    return b


__all__ = ["NEAR", "FAR", "DEFAULT_PLANES", "sweep_depths", "plane_sweep_cost"]
