"""Ray-casting renderer: RGB and ground-truth pinhole depth, one ray per image column.

Obstacles are vertical prisms from floor to ceiling, so a column's whole picture follows
from one horizontal ray. Column u has camera ray (x_n, *, 1), x_n = (u - cx) / fx. In
camera coordinates on the floor plane (X right, Z forward) the ray is t (x_n, 1): the
point at parameter t lies at pinhole depth Z = t, so the first hit's t is the depth.

Walls (one 2D hit per column: the smallest t > 0):
    segment A -> B (camera coordinates, dX = X_B - X_A, dZ = Z_B - Z_A): the ray meets
        its line at  t = (dX Z_A - dZ X_A) / (dX - dZ x_n),
        inside the segment iff x_n lies between X_A / Z_A and X_B / Z_B
        (after clipping the segment to Z >= T_MIN, so both ends are in front);
    circle (X_c, Z_c), radius R:  |t (x_n, 1) - (X_c, Z_c)|^2 = R^2  gives
        t = (b - sqrt(b^2 - a k)) / a,   a = 1 + x_n^2,  b = x_n X_c + Z_c,
        k = X_c^2 + Z_c^2 - R^2  (a hit iff the root is real and positive).
Segments that cannot appear in the field of view (image interval outside
[x_n(0), x_n(W-1)]) are culled first, so each column meets only the visible ones;
circles are few and all tried.

Rows (y_n = (v - cy) / fy, positive downwards). The floor lies h = altitude below the
camera and the ceiling H_c - h above it, so the planes' depths are
    Z_floor = h / y_n (y_n > 0),     Z_ceiling = (H_c - h) / (-y_n) (y_n < 0),
and the pixel (v, u) sees the wall if t(u) <= Z_plane(v), else the plane:
    depth(v, u) = min(t(u), Z_plane(v)).
The seen point is at height h - y_n t(u) on the wall, or at p + Z_plane(v) r(u) on the
floor or ceiling, with r(u) = f + x_n g the column's ray in world coordinates
(f = (cos yaw, sin yaw) forward, g = (sin yaw, -cos yaw) right). Its colour is
``gain * shade * (c0 + (c1 - c0) p)`` with the pattern p of ``textures.pattern``.

Scenes are closed (walls all around), so every pixel has a finite depth. The camera is
assumed outside every obstacle (the drone collides 0.5 m before touching one).
"""
from __future__ import annotations

import numpy as np

from .camera import Camera
from .scene import Scene, SceneBatch
from .textures import (CEILING_ID, D_AMP_B, D_AMP_N, D_C0, D_DC, D_INV_NS, D_INV_SU, D_INV_SV,
                       D_LB, D_LN, D_NOX, D_NOY, D_OX, D_OY, D_STAGGER, D_WB, D_WN, FLOOR_ID,
                       LIGHT, N_DERIVED, pattern_from_coords, wall_shade)

T_MIN = 1e-9          # hits closer than this (metres of depth) are ignored
CHUNK_PIXELS = 16384  # pixels shaded per pass (``_chunks``): temporaries stay in cache
ANGLE_SLACK = 1e-6    # radians of margin in the circle cull (keeps it conservative)
FEW_POSES = 4         # up to this many poses, cast every kept segment against every column

assert D_LN == D_LB + 1 and D_WN == D_WB + 1 and D_DC.start == D_C0.stop   # sliced below
assert (D_AMP_B, D_AMP_N) == (D_LB, D_LN)


def _compact(keep: np.ndarray, rows: np.ndarray):
    """Indices that gather the kept entries of each row to the front: keep (N, M) bool ->
    (order (N, K), valid (N, K)) with K the largest kept count (at least 1)."""
    if len(keep) == 1:
        order = np.flatnonzero(keep[0])
        if len(order):
            return order[None], np.ones((1, len(order)), bool)
    k = max(int(np.count_nonzero(keep, axis=1).max()), 1)
    if k == keep.shape[1]:
        return np.broadcast_to(np.arange(k), keep.shape), keep
    order = np.argsort(~keep, axis=1, kind="stable")[:, :k]
    return order, keep[rows, order]


def cast_columns(batch: SceneBatch, poses: np.ndarray, xn: np.ndarray) -> dict:
    """The nearest wall hit of each column ray (module docstring).

    batch of B = 1 or N worlds, poses (N, 3), xn (W,) column slopes (increasing). Returns
    a dict of (N, W) arrays: ``t`` pinhole depth of the hit; ``s`` texture coordinate along
    the surface; ``shade`` its wall shade (``textures.wall_shade`` of the normal); ``cos``
    |n . (x_n, 1)| for the unit normal n; ``app`` appearance id; and ``world`` (N, 1),
    the batch index of each pose's world.
    """
    with np.errstate(divide="ignore", invalid="ignore"):    # inf / NaN mark "no hit"
        return _cast_columns(batch, poses, np.asarray(xn, np.float64))


def _nearest_segments(X, Z, xn):
    """Nearest segment hit of every column: (t (N, W), segment index (N, W)); t = inf and
    index 0 where a column meets no segment.

    X, Z (N, 2, E): the camera coordinates of each segment's ends A (index 0) and B (1).
    Only the (segment, column) pairs that can hit are evaluated: each segment is clipped
    to Z >= T_MIN and kept iff its image interval [lo, hi] of slopes meets the view; its
    columns are those with lo <= x_n <= hi, a contiguous run [u_lo, u_hi) of the sorted
    x_n. For many poses the pairs are listed flat (a kept segment repeated once per column
    of its run), t = (dX Z_A - dZ X_A) / (dX - dZ x_n) is computed per pair, and the
    smallest t of each column is found with ``np.minimum.at`` (ties: the lowest segment
    index); for a few poses see ``_nearest_segments_padded``.
    """
    n, w = len(X), len(xn)
    # Both ends at once: end k is clipped towards the other end by the fraction f_k that
    # brings it to Z = T_MIN, f_k = (T_MIN - Z_k) / (Z_other - Z_k) (0 if already in front).
    dX, dZ = X[:, ::-1] - X, Z[:, ::-1] - Z                              # other end - this one
    f = np.where(Z < T_MIN, (T_MIN - Z) / dZ, 0.0)
    u = (X + dX * f) / (Z + dZ * f)                                      # clipped ends' slopes
    lo, hi = np.minimum(u[:, 0], u[:, 1]), np.maximum(u[:, 0], u[:, 1])
    keep = ((np.maximum(f[:, 0], f[:, 1]) < 1) & (hi >= xn[0]) & (lo <= xn[-1])
            & (hi - lo > 1e-12))
    Xa, Za, dX, dZ = X[:, 0], Z[:, 0], dX[:, 0], dZ[:, 0]                # (N, E); d = B - A
    num = dX * Za - dZ * Xa
    if n <= FEW_POSES:
        return _nearest_segments_padded(num, dX, dZ, xn, np.where(keep, lo, np.inf), hi, keep)
    pose, seg = np.nonzero(keep)                                         # pose-major, seg up
    u_lo = np.searchsorted(xn, lo[pose, seg], "left")
    count = np.maximum(np.searchsorted(xn, hi[pose, seg], "right") - u_lo, 0)
    start = np.cumsum(count) - count                                     # first pair of each
    # Per pair: its pixel n W + u (= arange + a per-segment offset) and its segment index.
    offset, seg_of = np.repeat(np.stack([pose * w + u_lo - start, seg]), count, axis=1)
    pixel = np.arange(len(offset)) + offset
    num, dX, dZ = np.repeat(np.stack([num[pose, seg], dX[pose, seg], dZ[pose, seg]]),
                            count, axis=1)
    t_pair = num / (dX - dZ * np.tile(xn, n)[pixel])
    t = np.full(n * w, np.inf)
    np.minimum.at(t, pixel, t_pair)
    first = np.full(n * w, X.shape[2], np.int64)                        # E: "none yet"
    win = t_pair == t[pixel]
    np.minimum.at(first, pixel[win], seg_of[win])
    first[first == X.shape[2]] = 0
    return t.reshape(n, w), first.reshape(n, w)


def _nearest_segments_padded(num, dX, dZ, xn, lo, hi, keep):
    """``_nearest_segments`` for a few poses, in fewer (larger) NumPy calls: every kept
    segment against every column, (N, W, K), masked to its interval [lo, hi] (lo = inf
    for the segments not kept)."""
    rows = np.arange(len(num))[:, None]
    order, _ = _compact(keep, rows)
    num, dX, dZ, lo, hi = (v[rows, order][:, None, :] for v in (num, dX, dZ, lo, hi))
    xw = xn[None, :, None]                                               # (1, W, 1)
    t_s = num / (dX - dZ * xw)                                           # (N, W, K)
    t_s = np.where((xw >= lo) & (xw <= hi), t_s, np.inf)
    k_s = np.argmin(t_s, axis=-1)
    return t_s[rows, np.arange(len(xn)), k_s], order[rows, k_s]


def _nearest_circles(Xc, Zc, R, xn, rows):
    """Nearest circle hit of every column: (t (N, W), circle index (N, W)), t = inf where
    none. t = (b - sqrt(b^2 - a k)) / a (module docstring). For many poses, tried only for
    the circles whose angular extent atan2(X_c, Z_c) +- asin(R / d), d = |(X_c, Z_c)|,
    meets the view [atan x_n(0), atan x_n(W-1)] (a conservative cull: the others cannot be
    hit); for a few poses culling costs more than it saves, and all are tried."""
    n = len(Xc)
    if n <= FEW_POSES:
        order, valid = None, R > 0                                       # padding has R = 0
    else:
        phi = np.arctan2(Xc, Zc)
        half = np.arcsin(np.minimum(R / np.hypot(Xc, Zc), 1.0))
        keep = ((R > 0) & (phi + half >= np.arctan(xn[0]) - ANGLE_SLACK)
                & (phi - half <= np.arctan(xn[-1]) + ANGLE_SLACK))
        if not keep.any():
            return np.full((n, len(xn)), np.inf), np.zeros((n, len(xn)), np.int64)
        order, valid = _compact(keep, rows)
        Xc, Zc, R = Xc[rows, order], Zc[rows, order], R[rows, order]
    k = np.where(valid, Xc * Xc + Zc * Zc - R * R, np.inf)[:, None, :]
    xw = xn[:, None]                                                     # (W, 1)
    b = Zc[:, None, :] + xw * Xc[:, None, :]                             # (N, W, C)
    a = 1.0 + xw * xw
    t_c = (b - np.sqrt(b * b - a * k)) / a                               # NaN: no hit
    t_c = np.where(t_c > T_MIN, t_c, np.inf)
    ic = np.argmin(t_c, axis=-1)
    return t_c[rows, np.arange(len(xn)), ic], (ic if order is None else order[rows, ic])


def _cast_columns(batch: SceneBatch, poses: np.ndarray, xn: np.ndarray) -> dict:
    """Body of ``cast_columns`` (run with floating-point warnings off)."""
    n = len(poses)
    rows = np.arange(n)[:, None]
    world = rows if len(batch) == n else np.zeros((n, 1), np.int64)
    p = poses[:, None, :2]                                               # (N, 1, 2)
    c, s = np.cos(poses[:, 2, None]), np.sin(poses[:, 2, None])          # (N, 1)

    # Segments in camera coordinates: X = (P - p).g, Z = (P - p).f, g = (s, -c), f = (c, s).
    ends = batch.seg_ab - p                                              # (N, 2E, 2)
    X = ends[..., 0] * s - ends[..., 1] * c
    Z = ends[..., 0] * c + ends[..., 1] * s
    e_count = X.shape[1] // 2
    X, Z = X.reshape(n, 2, e_count), Z.reshape(n, 2, e_count)           # ends A, B
    ts, iseg = _nearest_segments(X, Z, xn)

    # Circles: padding circles have R = 0 (culled).
    cx, cy = batch.circ_c[..., 0] - p[..., 0], batch.circ_c[..., 1] - p[..., 1]
    Xc, Zc = cx * s - cy * c, cx * c + cy * s                            # (N, C)
    R = batch.circ_r[world[:, 0]]
    tc, ic = _nearest_circles(Xc, Zc, R, xn, rows)

    # The winner's normal n (camera frame, facing the camera) and texture coordinate s.
    # Segment: n perpendicular to B - A, s = u0 + (hit - A).(B - A) / |B - A|.
    t = np.minimum(tc, ts)
    xa, za = X[rows, 0, iseg], Z[rows, 0, iseg]
    ex, ez = X[rows, 1, iseg] - xa, Z[rows, 1, iseg] - za
    length = batch.seg_len[world, iseg]
    tex_s = batch.seg_u0[world, iseg] + ((t * xn - xa) * ex + (t - za) * ez) / length
    flip = np.where(ex - ez * xn > 0, -1.0, 1.0) / length                # face the camera
    nx, nz = -ez * flip, ex * flip
    app = batch.seg_app[world, iseg]
    circle = tc < ts
    if circle.any():
        # Circle: n = (hit - centre) / R, s = R (world angle of n).
        radius = R[rows, ic]
        ncx = (t * xn - Xc[rows, ic]) / radius
        ncz = (t - Zc[rows, ic]) / radius
        angle = np.arctan2(ncz, ncx) + poses[:, 2, None] - 0.5 * np.pi
        nx, nz = np.where(circle, ncx, nx), np.where(circle, ncz, nz)
        tex_s = np.where(circle, radius * ((angle + np.pi) % (2 * np.pi) - np.pi), tex_s)
        app = np.where(circle, batch.circ_app[world, ic], app)
    # Shade with the world light l written in camera coordinates: (l.g, l.f).
    lx, lz = LIGHT[0] * s - LIGHT[1] * c, LIGHT[0] * c + LIGHT[1] * s
    return {"t": t, "s": tex_s, "shade": wall_shade(nx * lx + nz * lz),
            "cos": np.abs(nx * xn + nz), "app": app, "world": world}


def _check_camera(camera):
    if camera is None:
        return Camera()
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a Camera; got {type(camera).__name__}")
    return camera


def _as_batch(scenes, poses, name: str):
    """(SceneBatch, poses (N, 3) float64) from the arguments of the batched renderers."""
    if isinstance(scenes, Scene):
        batch = scenes.batch()
    elif isinstance(scenes, SceneBatch):
        batch = scenes
    elif isinstance(scenes, (list, tuple)):
        batch = SceneBatch(scenes)
    else:
        raise TypeError(f"{name}: scenes must be a Scene, a SceneBatch or a list of "
                        f"Scene; got {type(scenes).__name__}")
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3 or (len(batch) > 1 and len(poses) != len(batch)):
        want = "(N, 3)" if len(batch) == 1 else f"({len(batch)}, 3)"
        raise ValueError(f"{name}: poses must have shape {want} holding (x, y, yaw); "
                         f"got shape {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise ValueError(f"{name}: poses must be finite")
    return batch, poses


_CAMERA_CONSTANTS = {}


def _camera_constants(camera: Camera) -> dict:
    """Per-camera constants of the renderer, computed once per camera (Camera is frozen and
    hashable): the ray slopes, the floor/ceiling choice per row and the footprint factors
    L^2 / (fx max(c, 0.2 L)) of the module docstring's anti-aliasing (c the cosine term)."""
    key = camera
    if key not in _CAMERA_CONSTANTS:
        xn, yn = camera.column_rays(), camera.row_rays()
        l2_col, l2_row = 1.0 + xn * xn, 1.0 + yn * yn
        _CAMERA_CONSTANTS[key] = {
            "xn": xn, "yn": yn, "yn32": yn.astype(np.float32)[:, None],     # (H, 1)
            "floor": yn > 0, "abs_yn": np.abs(yn),
            "row_app": np.where(yn > 0, FLOOR_ID, CEILING_ID),
            "l2_col": l2_col, "cos_floor_col": 0.2 * np.sqrt(l2_col),
            "l2_row": l2_row,
            "col_src": np.arange(len(xn)), "row_src": len(xn) + np.arange(len(yn))[:, None],
            "den_row": camera.fx * np.maximum(np.abs(yn), 0.2 * np.sqrt(l2_row)),
        }
    return _CAMERA_CONSTANTS[key]


def _plane_depth(batch: SceneBatch, world: np.ndarray, const: dict) -> np.ndarray:
    """Floor (rows below the horizon) or ceiling depth per row, (N, H): h / |y_n|, with h
    the altitude or ceiling - altitude; inf at y_n = 0."""
    alt = batch.altitude[world]                                           # (N, 1)
    with np.errstate(divide="ignore"):
        return np.where(const["floor"], alt, batch.ceiling[world] - alt) / const["abs_yn"]


def render_depth_batch(scenes, poses, camera: Camera | None = None) -> np.ndarray:
    """Ground-truth depth only, (N, H, W) float32: ``render_batch`` without the colours.

    depth(v, u) = min(t(u), Z_plane(v)): the column's wall hit or the floor / ceiling,
    whichever is nearer. Several times faster than ``render_batch``, for agents trained on
    GT depth.
    """
    camera = _check_camera(camera)
    batch, poses = _as_batch(scenes, poses, "render_depth_batch")
    const = _camera_constants(camera)
    hit = cast_columns(batch, poses, const["xn"])
    z_plane = _plane_depth(batch, hit["world"], const)
    return np.minimum(hit["t"].astype(np.float32)[:, None, :],
                      z_plane.astype(np.float32)[:, :, None])


def render_batch(scenes, poses, camera: Camera | None = None):
    """Render N views: one per (world, pose), or N poses in one world.

    Args:
        scenes: a SceneBatch or a sequence of N Scene (world n seen from poses[n]), or one
            Scene (every pose in it).
        poses: (N, 3) world (x, y, yaw) in metres and radians.
        camera: a Camera (default Camera()).

    Returns:
        rgb (N, H, W, 3) uint8 and depth (N, H, W) float32 (pinhole depth, metres).
    """
    camera = _check_camera(camera)
    batch, poses = _as_batch(scenes, poses, "render_batch")
    with np.errstate(divide="ignore", invalid="ignore"):   # horizon rows: x / 0, inf * 0
        return _shade_pixels(batch, poses, camera)


def _faded_weights(q, footprint):
    """``textures.fade`` for both patterns at once: (..., 2) = (a_b w_b, a_n w_n) with
    a = clip((L / f - 1) / 2, 0, 1), L the columns D_LB, D_LN of q (..., N_DERIVED), w its
    columns D_WB, D_WN and f the footprint (...)."""
    a = q[..., D_LB:D_LN + 1] * (0.5 / footprint)[..., None] - 0.5
    return np.minimum(np.maximum(a, 0.0), 1.0) * q[..., D_WB:D_WN + 1]


# Texture-lattice scales and offsets of the four lattice coordinates c = 2 pattern + axis
# (pattern 0 blocks, 1 noise; axis 0 along s, 1 along h; ``textures.texel_coords``).
_SCALES = (D_INV_SU, D_INV_SV, D_INV_NS, D_INV_NS)
_OFFSETS = (D_OX, D_OY, D_NOX, D_NOY)


def _chunks(n: int, h: int, w: int):
    """The pieces of ``_shade_pixels``'s per-pixel work, (frames a:b, rows r0:r1), each of
    about ``CHUNK_PIXELS`` pixels so that its temporaries stay in cache: whole frames, a
    few at a time, when a frame is smaller than that, else bands of rows of one frame."""
    if h * w <= CHUNK_PIXELS:
        step = CHUNK_PIXELS // (h * w)
        for a in range(0, n, step):
            yield a, min(a + step, n), 0, h
    else:
        step = max(1, CHUNK_PIXELS // w)
        for a in range(n):
            for r0 in range(0, h, step):
                yield a, a + 1, r0, min(r0 + step, h)


def _shade_pixels(batch: SceneBatch, poses: np.ndarray, camera: Camera):
    """Body of ``render_batch``: cast the columns, then depth and colour of every pixel.

    Pixel (v, u) sees the wall of column u if t(u) <= Z_plane(v), else the floor or the
    ceiling of row v. So every constant the pattern and the colour need (appearance,
    faded weights, shaded colours) is a per-column value on walls and a per-row value on
    the planes. They are computed once per frame into one table of W + H rows (columns
    first, then rows) and gathered for all pixels by a single ``take`` with the index
        src(v, u) = u if the pixel sees the wall, else W + v.
    Only the texture coordinates are truly per pixel:
        walls   (s, h) = (s(u), altitude - y_n(v) t(u)),
        planes  (s, h) = (x, y) + Z_plane(v) r(u),
    each picked by one ``np.where``. The per-pixel work runs on pieces of about
    ``CHUNK_PIXELS`` pixels (``_chunks``) so that its temporaries stay in cache; a single
    frame of up to that size (64x208 included) is one piece, with no loop overhead.
    Every float32 operation is the one of the reference formulas, in the same order, so
    the image does not depend on the chunking or on the batch size.
    """
    const = _camera_constants(camera)
    xn = const["xn"]
    hit = _cast_columns(batch, poses, xn)
    world = hit["world"]                                                  # (N, 1)
    n, (h, w) = len(poses), camera.shape
    f32 = np.float32
    z_plane = _plane_depth(batch, world, const)                           # (N, H)

    # The table (N, W + H, N_DERIVED): the derived constants (``textures.derived_table``)
    # of each column's wall and of each row's plane, one ``take`` from batch.tex, with
    # the columns D_AMP_B, D_AMP_N replaced by the faded pattern weights and the colour
    # columns scaled by the shade (1 on the planes; plus 1/2 on c0, so that truncation
    # rounds). The footprint of a pixel is f = t L^2 / (fx max(|n . ray|, 0.2 L)) on the
    # wall of a column and f = Z_plane L^2 / (fx max(|y_n|, 0.2 L)) on the plane of a row.
    app = np.empty((n, w + h), np.int64)                                 # appearance ids
    app[:, :w], app[:, w:] = hit["app"], const["row_app"]
    app += world * batch.tex.shape[1]                                     # rows of batch.tex
    table = batch.tex.reshape(-1, N_DERIVED).take(app, axis=0)
    f_col = hit["t"] * const["l2_col"] / (camera.fx * np.maximum(hit["cos"],
                                                                   const["cos_floor_col"]))
    f_row = z_plane * const["l2_row"] / const["den_row"]
    table[..., D_AMP_B:D_AMP_N + 1] = _faded_weights(table, np.concatenate([f_col, f_row], 1))
    shade = np.concatenate([hit["shade"], np.ones((n, h))], axis=1)
    colours = table[..., D_C0.start:D_DC.stop] * shade[..., None]         # float64 ...
    colours[..., :3] += 0.5
    table[..., D_C0.start:D_DC.stop] = colours                            # ... rounded once
    table = table.reshape(-1, N_DERIVED)                                  # (N (W + H), D)
    stagger = bool(table[:, D_STAGGER].any())

    # Per-frame inputs of the texture coordinates, float32.
    t32 = hit["t"].astype(f32)                                            # (N, W)
    zp32 = z_plane.astype(f32)                                            # (N, H)
    s32 = hit["s"].astype(f32)                                            # (N, W)
    alt32 = batch.altitude[world].astype(f32)                             # (N, 1)
    cos, sin = np.cos(poses[:, 2, None]), np.sin(poses[:, 2, None])
    rx, ry = (cos + xn * sin).astype(f32), (sin - xn * cos).astype(f32)   # r(u), (N, W)
    x0, y0 = poses[:, 0, None].astype(f32), poses[:, 1, None].astype(f32)  # (N, 1)

    depth = np.empty((n, h, w), f32)
    rgb = np.empty((n, h, w, 3), np.uint8)
    for a, b, r0, r1 in _chunks(n, h, w):
        m = b - a
        t, zp = t32[a:b, None, :], zp32[a:b, r0:r1, None]                 # (m, 1, W), (m, R, 1)
        wall = t <= zp                                                    # (m, R, W)
        np.minimum(t, zp, out=depth[a:b, r0:r1])
        src = np.where(wall, const["col_src"], const["row_src"][r0:r1])   # (m, R, W)
        if m > 1:
            src += ((w + h) * np.arange(a, b))[:, None, None]             # the frame's rows
        elif a:
            src += (w + h) * a
        # From here on every per-pixel array is flat, (P,) with P = m R W pixels: the
        # gathered constants k[:, j] are strided views, and 1-D loops over them stay fast.
        k = table.take(src.reshape(-1), axis=0)                           # (P, D)
        # Texture coordinates (s, h) of every pixel, then the four lattice coordinates.
        sh = (np.where(wall, s32[a:b, None, :], x0[a:b, :, None] + zp * rx[a:b, None, :]),
              np.where(wall, alt32[a:b, :, None] - const["yn32"][r0:r1] * t,
                       y0[a:b, :, None] + zp * ry[a:b, None, :]))
        sh = [x.reshape(-1) for x in sh]                                  # (s, h), 2 x (P,)
        coords = np.empty((4, wall.size), f32)
        for c in range(4):
            np.multiply(sh[c % 2], k[:, _SCALES[c]], out=coords[c])
            np.add(coords[c], k[:, _OFFSETS[c]], out=coords[c])
        p = pattern_from_coords(coords.reshape(2, 2, -1), k[:, D_AMP_B:D_AMP_N + 1].T,
                                k[:, D_STAGGER] if stagger else None)
        # colour = shade * gain * 255 (c0 + (c1 - c0) p) lies in [0, 255] for p in [0, 1];
        # the cast to uint8 truncates (the + 1/2 in the table makes it round). Computed
        # straight into the pixel-major (P, 3) layout of the image.
        out, colour = rgb[a:b, r0:r1].reshape(-1, 3), np.empty_like(p)
        for c in range(3):
            np.multiply(k[:, D_DC.start + c], p, out=colour)
            np.add(colour, k[:, D_C0.start + c], out=out[:, c], casting="unsafe")
    return rgb, depth


def render(scene: Scene, pose, camera: Camera | None = None):
    """Render one view: pose (3,) = (x, y, yaw) -> rgb (H, W, 3) uint8, depth (H, W) float32."""
    if not isinstance(scene, Scene):
        raise TypeError(f"render: scene must be a Scene; got {type(scene).__name__}")
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (3,):
        raise ValueError(f"render: pose must have shape (3,) holding (x, y, yaw); got shape "
                         f"{pose.shape}")
    rgb, depth = render_batch(scene, pose[None], camera)
    return rgb[0], depth[0]


def depth_to_ray_length(depth, camera: Camera) -> np.ndarray:
    """Convert pinhole depth Z to the length of the ray, Z sqrt(1 + x_n^2 + y_n^2)."""
    xn, yn = camera.column_rays(), camera.row_rays()
    return np.asarray(depth) * np.sqrt(1.0 + xn[None, :] ** 2 + yn[:, None] ** 2)


__all__ = ["render", "render_batch", "cast_columns", "depth_to_ray_length"]
