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
circles are few: all tried for one pose, culled by their angular extent for several.

Rows (y_n = (v - cy) / fy, positive downwards). The floor lies h = altitude below the
camera and the ceiling H_c - h above it, so the planes' depths are
    Z_floor = h / y_n (y_n > 0),     Z_ceiling = (H_c - h) / (-y_n) (y_n < 0),
and the pixel (v, u) sees the wall if t(u) <= Z_plane(v), else the plane:
    depth(v, u) = min(t(u), Z_plane(v)).
The seen point is at height h - y_n t(u) on the wall, or at p + Z_plane(v) r(u) on the
floor or ceiling, with r(u) = f + x_n g the column's ray in world coordinates
(f = (cos yaw, sin yaw) forward, g = (sin yaw, -cos yaw) right). Its colour is
``gain * shade * (c0 + (c1 - c0) p)`` with the pattern p of ``textures.py``.

Scenes are closed (walls all around), so every pixel has a finite depth. The camera is
assumed outside every obstacle (the drone collides 0.5 m before touching one).
"""
from __future__ import annotations

import numpy as np

from .camera import Camera
from .scene import Scene, SceneBatch
from .textures import (CEILING_ID, D_C0, D_DC, D_INV_NS, D_INV_SU, D_INV_SV,
                       D_LB, D_LN, D_NOX, D_NOY, D_OX, D_OY, D_STAGGER, D_WB, D_WN, FLOOR_ID,
                       LIGHT, N_DERIVED, derived_table, pattern_from_coords, wall_shade)

T_MIN = 1e-9          # hits closer than this (metres of depth) are ignored
CHUNK_PIXELS = 16384  # pixels shaded per pass (``_chunks``): temporaries stay in cache
ANGLE_SLACK = 1e-6    # radians of margin in the circle cull (keeps it conservative)

assert D_LN == D_LB + 1 and D_WN == D_WB + 1 and D_DC.start == D_C0.stop   # sliced below


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


def _segment_intervals(seg, xn):
    """Clip each segment to Z >= T_MIN and find its image interval of slopes.

    seg (N, 2, 2, E): camera coordinates (X, Z) of each segment's ends A (index 0) and B
    (1). Returns d = other end - this end (N, 2, 2, E), the interval [lo, hi] (N, E) of
    the clipped segment, ``keep`` (N, E) (in front of the camera, not degenerate, and
    overlapping the view [xn[0], xn[-1]]) and num = dX Z_A - dZ X_A (N, E), the numerator
    of t = num / (dX - dZ x_n) (module docstring).
    """
    # Both ends at once: end k is clipped towards the other end by the fraction f_k that
    # brings it to Z = T_MIN, f_k = (T_MIN - Z_k) / (Z_other - Z_k) (0 if already in front).
    d = seg[:, :, ::-1] - seg
    z = seg[:, 1]
    f = np.where(z < T_MIN, (T_MIN - z) / d[:, 1], 0.0)                  # (N, 2, E)
    clipped = seg + d * f[:, None]
    u = clipped[:, 0] / clipped[:, 1]                                    # clipped ends' slopes
    lo, hi = np.minimum(u[:, 0], u[:, 1]), np.maximum(u[:, 0], u[:, 1])
    keep = ((np.maximum(f[:, 0], f[:, 1]) < 1) & (hi >= xn[0]) & (lo <= xn[-1])
            & (hi - lo > 1e-12))
    prod = d[:, :, 0] * seg[:, ::-1, 0]                                  # dX Z_A, dZ X_A
    return d, lo, hi, keep, prod[:, 0] - prod[:, 1]


def _cast_columns(batch: SceneBatch, poses: np.ndarray, xn: np.ndarray) -> dict:
    """Body of ``cast_columns`` (run with floating-point warnings off). Two paths with
    bit-identical results: one pose goes to ``_cast_one``; more poses go to
    ``_cast_many``, which evaluates only the (surface, column) pairs that can hit."""
    n = len(poses)
    if n == 1:
        return _cast_one(batch, poses, xn)
    world = np.arange(n) if len(batch) == n else np.zeros(n, np.int64)
    c, s = np.cos(poses[:, 2, None]), np.sin(poses[:, 2, None])          # (N, 1)

    # Segment ends and circle centres P in camera coordinates, all in one pass:
    # X = (P - p).g, Z = (P - p).f with g = (s, -c), f = (c, s); (-c) y added is the same
    # float as c y subtracted.
    rel = batch.points - poses[:, :2, None]                              # (N, 2, 2E + C)
    rot = np.concatenate([s, c, -c, s], axis=1)[:, :, None]              # (N, 4, 1)
    xz = rel[:, :1] * rot[:, :2] + rel[:, 1:] * rot[:, 2:]               # (N, 2, 2E + C)
    e_count = batch.seg_len.shape[1]
    seg = np.ascontiguousarray(xz[:, :, :2 * e_count]).reshape(n, 2, 2, e_count)  # X/Z, A/B
    d, lo, hi, keep, num = _segment_intervals(seg, xn)
    Xc, Zc = xz[:, 0, 2 * e_count:], xz[:, 1, 2 * e_count:]              # (N, C)
    out = _cast_many(batch, world, xn, seg, d, lo, hi, keep, num, Xc, Zc, poses[:, 2, None],
                     c, s)
    out["world"] = world[:, None]
    return out


def _cast_many(batch, world, xn, seg, d, lo, hi, keep, num, Xc, Zc, yaw, c, s) -> dict:
    """``_cast_columns`` for many poses: only the (surface, column) pairs that can hit are
    evaluated, listed flat, segments and circles together.

    A kept segment can hit only the columns with lo <= x_n <= hi, a contiguous run of the
    sorted x_n; a circle only those whose ray angle atan x_n lies within its angular
    extent atan2(X_c, Z_c) +- asin(R / |(X_c, Z_c)|) (widened by ANGLE_SLACK to stay
    conservative). Each candidate surface is repeated once per column of its run, its t
    computed per pair, and the smallest t of each column found with ``np.minimum.at``.
    Ties go to the lowest surface id, with the E segments numbered before the C circles:
    the same winner as the single-pose path (a circle wins only if strictly nearer). A
    column that meets nothing gets t = inf and segment 0, as in the single-pose path.

    world (N,), yaw, c, s (N, 1); the other arguments as in ``_cast_columns``. Returns
    the dict of ``cast_columns`` without "world".
    """
    n, w = len(world), len(xn)
    e, n_circ = keep.shape[1], Xc.shape[1]
    one_world = len(batch) == 1
    R = batch.circ_r[0] if one_world else batch.circ_r[world]            # (C,) or (N, C)
    R = np.broadcast_to(R, Xc.shape)
    phi = np.arctan2(Xc, Zc)
    half = np.arcsin(np.minimum(R / np.hypot(Xc, Zc), 1.0))

    # Candidates: flat index pose * E + segment (resp. pose * C + circle) and the run of
    # columns [first, stop) each can hit.
    cand_s = np.flatnonzero(keep)
    cand_c = np.flatnonzero(R > 0)                                       # not padding
    angle = np.arctan(xn)
    first = np.concatenate([np.searchsorted(xn, lo.ravel().take(cand_s), "left"),
                            np.searchsorted(angle, (phi - half).ravel().take(cand_c)
                                            - ANGLE_SLACK, "left")])
    stop = np.concatenate([np.searchsorted(xn, hi.ravel().take(cand_s), "right"),
                           np.searchsorted(angle, (phi + half).ravel().take(cand_c)
                                           + ANGLE_SLACK, "right")])
    count = np.maximum(stop - first, 0)
    start = np.cumsum(count) - count                                     # its first pair
    n_seg_pairs = int(count[:len(cand_s)].sum())
    # Per pair: the candidate it belongs to and its pixel pose * W + u (u = first + the
    # pair's rank within its candidate's run).
    cand = np.repeat(np.arange(len(count)), count)
    pose = np.concatenate([cand_s // e, cand_c // n_circ])
    pixel = np.arange(len(cand)) + (pose * w + first - start).take(cand)
    x = np.tile(xn, n).take(pixel)                                       # its x_n
    t_pair = np.empty(len(cand))
    # Segment pairs: t = num / (dX - dZ x_n), with the values gathered first for the
    # candidates, then for their pairs (candidates in order: cache-friendly reads).
    cand_seg = cand[:n_seg_pairs]
    num_p, dx_p, dz_p = (v.reshape(-1).take(cand_s).take(cand_seg)
                         for v in (num, d[:, 0, 0], d[:, 1, 0]))
    np.divide(num_p, dx_p - dz_p * x[:n_seg_pairs], out=t_pair[:n_seg_pairs])
    # Circle pairs: t = (b - sqrt(b^2 - a k)) / a, a = 1 + x_n^2, b = Z_c + x_n X_c,
    # k = X_c^2 + Z_c^2 - R^2 (NaN when the ray misses: dropped below, like t <= T_MIN).
    k = Xc * Xc + Zc * Zc - R * R
    circ_vals = np.stack([Xc, Zc, k]).reshape(3, -1)                      # (3, N C)
    xc_p, zc_p, k_p = circ_vals.take(cand_c.take(cand[n_seg_pairs:] - len(cand_s)), axis=1)
    xr = x[n_seg_pairs:]
    a = 1.0 + xr * xr
    b = zc_p + xr * xc_p
    t_c = (b - np.sqrt(b * b - a * k_p)) / a
    t_pair[n_seg_pairs:] = np.where(t_c > T_MIN, t_c, np.inf)
    # Circle pairs that miss are dropped, so that a column with no hit at all keeps the
    # segment choice of the single-pose path.
    drop = n_seg_pairs + np.flatnonzero(~(t_c > T_MIN))
    if len(drop):
        t_pair, pixel, cand = (np.delete(v, drop) for v in (t_pair, pixel, cand))
    # Surface id of each candidate: the segment, or E + the circle.
    surf = np.concatenate([cand_s % e, e + cand_c % n_circ])

    # The nearest pair of each column, then the lowest surface id among equal nearest.
    t = np.full(n * w, np.inf)
    np.minimum.at(t, pixel, t_pair)
    win = np.flatnonzero(t_pair == t.take(pixel))
    best = np.full(n * w, e + n_circ)                                    # "none yet"
    pixel_win, surf_win = pixel.take(win), surf.take(cand.take(win))
    best[pixel_win] = surf_win
    if len(win) > np.count_nonzero(best < e + n_circ):
        # Some column has several equally near pairs (a ray through a corner shared by
        # two segments): the lowest id wins. Rare, so the slower ``minimum.at`` is
        # run only then.
        np.minimum.at(best, pixel_win, surf_win)
    best[best == e + n_circ] = 0

    # Segment surface of every column (a column won by a circle reads some segment and
    # is overwritten below): its ends, from this pose, and length, u0, app, from its world.
    seg_ix = (np.arange(n) * e)[:, None] + best.reshape(n, w)            # pose * E + id
    xa, za, ex, ez = (v.reshape(-1).take(seg_ix, mode="clip")
                      for v in (seg[:, 0, 0], seg[:, 1, 0], d[:, 0, 0], d[:, 1, 0]))
    world_ix = best.reshape(n, w) + (0 if one_world else (world * e)[:, None])  # world E + id
    length, u0, app = (v.reshape(-1).take(world_ix, mode="clip")
                       for v in (batch.seg_len, batch.seg_u0, batch.seg_app))
    t = t.reshape(n, w)
    tex_s, nx, nz = _segment_surface(t, xn, xa, za, ex, ez, length, u0)
    app = app.astype(np.int64)
    # Circle surface of the columns a circle won, written over them.
    hit_c = np.flatnonzero(best >= e)
    if len(hit_c):
        pose_c, ic = hit_c // w, best.take(hit_c) - e
        circ_ix = pose_c * n_circ + ic
        world_c = ic if one_world else world.take(pose_c) * n_circ + ic
        s_c, nx_c, nz_c = _circle_surface(
            t.reshape(-1).take(hit_c), xn.take(hit_c % w), Xc.reshape(-1).take(circ_ix),
            Zc.reshape(-1).take(circ_ix), batch.circ_r.reshape(-1).take(world_c),
            yaw.reshape(-1).take(pose_c))
        for full, part in ((tex_s, s_c), (nx, nx_c), (nz, nz_c)):
            full.reshape(-1)[hit_c] = part
        app.reshape(-1)[hit_c] = batch.circ_app.reshape(-1).take(world_c)
    return _shade_columns(t, tex_s, nx, nz, app, xn, c, s)


def _cast_one(batch: SceneBatch, poses: np.ndarray, xn: np.ndarray) -> dict:
    """``_cast_columns`` for one pose, in as few NumPy calls as possible (a frame of 104
    rays is dominated by the number of calls, not by arithmetic): the same arithmetic as
    the batched path, on 2-D arrays, with the segments and the circles of every column
    compared by one ``argmin``."""
    yaw = poses[:, 2]
    c, s = np.cos(yaw).item(), np.sin(yaw).item()                       # Python floats
    w = len(xn)
    # Camera coordinates of the segment ends and circle centres (see _cast_columns).
    rel = batch.points[0] - poses[0, :2, None]                           # (2, 2E + C)
    xz = rel[0] * np.array([[s], [c]]) + rel[1] * np.array([[-c], [s]])
    e_count = batch.seg_len.shape[1]
    seg = xz[:, :2 * e_count].reshape(1, 2, 2, e_count)
    d, lo, hi, keep, num = _segment_intervals(seg, xn)
    # Kept segments (at least one, so that a column that meets nothing still finds a
    # segment, with t = inf, as in the batched path).
    order = np.flatnonzero(keep[0])
    if not len(order):
        order = np.zeros(1, np.int64)
        lo = np.full_like(lo, np.inf)
    k = len(order)
    # Rows: num, dX, dZ, lo, hi, X_A, Z_A of each kept segment, (7, K).
    kept = np.concatenate([num, d[0, :, 0], lo, hi, seg[0, :, 0]]).take(order, axis=1)
    t_s = kept[0, :, None] / (kept[1, :, None] - kept[2, :, None] * xn)     # (K, W)
    t_s = np.where((xn >= kept[3, :, None]) & (xn <= kept[4, :, None]), t_s, np.inf)
    # Circles, all of them (padding ones have k = inf: no hit).
    circ = xz[:, 2 * e_count:]                                           # (2, C)
    sq = circ * circ
    kc = ((sq[0] + sq[1]) - batch.circ_r2[0] + batch.circ_inf[0])[:, None]
    b = circ[1, :, None] + xn * circ[0, :, None]                         # (C, W)
    a = 1.0 + xn * xn
    t_c = (b - np.sqrt(b * b - a * kc)) / a                              # NaN: no hit
    t_c = np.where(t_c > T_MIN, t_c, np.inf)
    # One argmin over segments then circles: the first minimum wins, so a tie goes to the
    # segment, as t = min(t_c, t_s) with circle = t_c < t_s does in the batched path.
    both = np.concatenate([t_s, t_c])                                    # (K + C, W)
    j = np.argmin(both, axis=0)
    t = both.take(j * w + np.arange(w))
    circle = j >= k
    # Gathers with mode="clip": a column won by the other kind reads some valid entry,
    # whose values the circle/segment choice in _surface then discards.
    xa, za, ex, ez = kept[[5, 6, 1, 2]].take(j, axis=1, mode="clip")
    consts = batch.seg_consts[0].take(order.take(j, mode="clip"), axis=0)    # (W, 3)
    ic = j - k
    centre = circ.take(ic, axis=1, mode="clip")
    out = _surface(t, circle, xn, (xa, za, ex, ez), consts[:, 0], consts[:, 1], consts[:, 2],
                   (centre[0], centre[1], batch.circ_r[0].take(ic, mode="clip"),
                    batch.circ_app[0].take(ic, mode="clip")), yaw.item(), c, s)
    out = {key: v[None] for key, v in out.items()}
    out["world"] = np.zeros((1, 1), np.int64)
    return out


def _segment_surface(t, xn, xa, za, ex, ez, length, u0):
    """Texture coordinate s and unit normal (n_x, n_z) of segment hits at depth t: s = u0
    + (hit - A).(B - A) / |B - A|, n perpendicular to B - A and facing the camera; the
    segment values (X_A, Z_A, dX, dZ), length and u0 broadcast against t."""
    txn = t * xn
    tex_s = u0 + ((txn - xa) * ex + (t - za) * ez) / length
    flip = np.where(ex - ez * xn > 0, -1.0, 1.0) / length                # face the camera
    return tex_s, -ez * flip, ex * flip


def _circle_surface(t, xn, cx, cz, radius, yaw):
    """Texture coordinate s and unit normal of circle hits at depth t: n = (hit - centre)
    / R, s = R (world angle of n), the angle wrapped to [-pi, pi)."""
    ncx = (t * xn - cx) / radius
    ncz = (t - cz) / radius
    angle = np.arctan2(ncz, ncx) + yaw - 0.5 * np.pi
    return radius * ((angle + np.pi) % (2 * np.pi) - np.pi), ncx, ncz


def _shade_columns(t, tex_s, nx, nz, app, xn, c, s) -> dict:
    """The dict of ``cast_columns`` (without "world") from the winning surfaces: the wall
    shade with the world light l written in camera coordinates, (l.g, l.f), and the cosine
    term |n . (x_n, 1)|."""
    lx, lz = LIGHT[0] * s - LIGHT[1] * c, LIGHT[0] * c + LIGHT[1] * s
    return {"t": t, "s": tex_s, "shade": wall_shade(nx * lx + nz * lz),
            "cos": np.abs(nx * xn + nz), "app": app}


def _surface(t, circle, xn, seg, length, u0, seg_app, circ, yaw, c, s) -> dict:
    """What the renderer needs of each column's winning surface, from its hit depth t,
    ``circle`` (True where a circle won) and the winner's segment values seg = (X_A, Z_A,
    dX, dZ), length, u0, app (float) and circle values circ = (X_c, Z_c, R, app); each
    (..., W) (those of the losing kind are ignored). yaw, c = cos yaw, s = sin yaw: (N, 1)
    arrays or floats. Returns the dict of ``cast_columns`` without "world"."""
    tex_s, nx, nz = _segment_surface(t, xn, *seg, length, u0)
    app = seg_app.astype(np.int64)
    if circle.any():
        cx, cz, radius, circ_app = circ
        tex_c, ncx, ncz = _circle_surface(t, xn, cx, cz, radius, yaw)
        nx, nz = np.where(circle, ncx, nx), np.where(circle, ncz, nz)
        tex_s = np.where(circle, tex_c, tex_s)
        app = np.where(circle, circ_app, app)
    return _shade_columns(t, tex_s, nx, nz, app, xn, c, s)


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
    hashable): the ray slopes, the floor/ceiling choice per row, the footprint factors
    L^2 / (fx max(c, 0.2 L)) of the module docstring's anti-aliasing (c the cosine term)
    and, for one frame, the table row of each pixel's wall (its column u) and of its
    plane (W + its row v; see ``_shade_pixels``)."""
    key = camera
    if key not in _CAMERA_CONSTANTS:
        xn, yn = camera.column_rays(), camera.row_rays()
        h, w = camera.shape
        l2_col, l2_row = 1.0 + xn * xn, 1.0 + yn * yn
        col_u = np.ascontiguousarray(np.broadcast_to(np.arange(w), (h, w)))
        row_v = np.ascontiguousarray(np.broadcast_to(np.arange(h)[:, None], (h, w)))
        _CAMERA_CONSTANTS[key] = {
            "xn": xn, "yn": yn, "yn32": yn.astype(np.float32)[:, None],     # (H, 1)
            "floor": yn > 0, "abs_yn": np.abs(yn),
            "row_app": np.where(yn > 0, FLOOR_ID, CEILING_ID),
            "l2_col": l2_col, "cos_floor_col": 0.2 * np.sqrt(l2_col),
            "l2_row": l2_row,
            "den_row": camera.fx * np.maximum(np.abs(yn), 0.2 * np.sqrt(l2_row)),
            "col_u": col_u, "row_src": row_v + w,                            # (H, W) each
        }
    return _CAMERA_CONSTANTS[key]


# Columns of the per-pixel tables (``_shade_pixels``), rows of 8 float32: 32 bytes is the
# widest row that ``np.take`` copies without a memmove per row.
# Table A: the four lattice coordinates c = 2 pattern + axis (pattern 0 blocks, 1 noise;
# axis 0 along s, 1 along h; ``textures.pattern_from_coords``) are c = x * scale + offset, x = s
# or h; A holds the four scales, then the four offsets.
_COORD_COLS = [D_INV_SU, D_INV_SV, D_INV_NS, D_INV_NS, D_OX, D_OY, D_NOX, D_NOY]
# Table C: the shaded colours (c0 with + 1/2 for rounding, then c1 - c0), then the faded
# pattern weights (a_b w_b, a_n w_n).
_C_COLOURS, _C_AMP = slice(0, 6), slice(6, 8)


def _scene_planes(scene: Scene, camera: Camera, const: dict) -> dict:
    """The floor and ceiling constants of one world seen by one camera, cached on the scene.

    They do not depend on the pose: a row v sees the floor (or the ceiling) at depth
    Z_plane(v) = h / |y_n| (h the altitude, or ceiling - altitude; inf at y_n = 0), with a
    footprint of Z_plane L^2 / (fx max(|y_n|, 0.2 L)) and shade 1. Returns "zp" (H,)
    float64, "zp32" (H,) float32, "zp_coord" (zp32 with 0 for inf: what the texture
    coordinates use, see ``_shade_pixels``) and the rows of the per-pixel tables: "a"
    (H, 8), "c" (H, 8) and "stagger" (H,) float32.
    """
    key = ("planes", camera)
    if key not in scene._cache:
        alt = scene.altitude
        with np.errstate(divide="ignore"):
            zp = np.where(const["floor"], alt, scene.ceiling - alt) / const["abs_yn"]
        q = derived_table(scene.appearances).take(const["row_app"], axis=0)   # (H, D)
        footprint = zp * const["l2_row"] / const["den_row"]
        c = np.zeros((len(zp), 8), np.float32)
        colours = q[:, D_C0.start:D_DC.stop].astype(np.float64)           # shade 1
        colours[:, :3] += 0.5
        c[:, _C_COLOURS], c[:, _C_AMP] = colours, _faded_weights(q, footprint)
        zp32 = zp.astype(np.float32)
        scene._cache[key] = {"zp": zp, "zp32": zp32,
                             "zp_coord": np.where(np.isinf(zp32), np.float32(0), zp32),
                             "a": np.ascontiguousarray(q[:, _COORD_COLS]), "c": c,
                             "stagger": q[:, D_STAGGER].copy()}
    return scene._cache[key]


def _plane_tables(batch: SceneBatch, camera: Camera, const: dict) -> dict:
    """``_scene_planes`` of every world of the batch, stacked: "zp", "zp32", "zp_coord"
    (B, H), "a" (B H, 8), "c" (B H, 8), "stagger" (B H,), plus "any_stagger". Cached on the
    batch until a world changes (``SceneBatch.set``)."""
    scenes = batch.scenes
    cached = batch._cache.get(("planes", camera))
    if cached is not None and len(cached[0]) == len(scenes) and all(
            a is b for a, b in zip(cached[0], scenes)):
        return cached[1]
    per_world = [_scene_planes(sc, camera, const) for sc in scenes]
    tables = {k: (np.stack if k.startswith("zp") else np.concatenate)([p[k] for p in per_world])
              for k in per_world[0]}
    # Whether any appearance of these worlds staggers its blocks (else the pattern can
    # skip the stagger step; with it, a stagger of 0 gives the same texels).
    tables["any_stagger"] = bool(batch.tex[..., D_STAGGER].any())
    batch._cache[("planes", camera)] = (list(scenes), tables)
    return tables


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
    zp32 = _plane_tables(batch, camera, const)["zp32"][hit["world"][:, 0]]  # (N, H)
    return np.minimum(hit["t"].astype(np.float32)[:, None, :], zp32[:, :, None])


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
    """The faded weights of both patterns: (..., 2) = (a_b w_b, a_n w_n) with
    a = clip((L / f - 1) / 2, 0, 1), L the columns D_LB, D_LN of q (..., N_DERIVED), w its
    columns D_WB, D_WN and f the footprint (...)."""
    a = q[..., D_LB:D_LN + 1] * (0.5 / footprint)[..., None] - 0.5
    return np.minimum(np.maximum(a, 0.0), 1.0) * q[..., D_WB:D_WN + 1]


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
    ceiling of row v. So every constant the pattern and the colour need (lattice scales
    and offsets, faded weights, shaded colours) is a per-column value on walls and a
    per-row value on the planes. They sit in small tables, one row per column of each
    frame (N W rows, computed per frame) followed by one row per image row of each world
    (B H rows: they do not depend on the pose, so ``_plane_tables`` caches them), and are
    gathered for all pixels by one ``take`` per table with the index
        src(n, v, u) = n W + u if the pixel sees the wall, else N W + world(n) H + v.
    Only the texture coordinates are truly per pixel:
        walls   (s, h) = (s(u), altitude - y_n(v) t(u)),
        planes  (s, h) = (x, y) + Z_plane(v) r(u).
    The per-pixel work runs on pieces of about ``CHUNK_PIXELS`` pixels (``_chunks``) so
    that its temporaries stay in cache; a single frame of up to that size (64x208
    included) is one piece, with no loop overhead. Every float32 operation is the one of
    the reference formulas, in the same order, so the image does not depend on the
    chunking or on the batch size.
    """
    const = _camera_constants(camera)
    xn = const["xn"]
    hit = _cast_columns(batch, poses, xn)
    world = hit["world"][:, 0]                                            # (N,)
    n, (h, w) = len(poses), camera.shape
    f32 = np.float32
    planes = _plane_tables(batch, camera, const)

    # The column rows of the tables: the derived constants (``textures.derived_table``) of
    # each column's wall, with the faded pattern weights for a footprint of
    # f = t L^2 / (fx max(|n . ray|, 0.2 L)) and the colours scaled by the wall's shade.
    app = hit["app"] + world[:, None] * batch.tex.shape[1]               # rows of batch.tex
    q = batch.tex.reshape(-1, N_DERIVED).take(app, axis=0)               # (N, W, D)
    f_col = hit["t"] * const["l2_col"] / (camera.fx * np.maximum(hit["cos"],
                                                                   const["cos_floor_col"]))
    colours = q[..., D_C0.start:D_DC.stop] * hit["shade"][..., None]      # float64 ...
    colours[..., :3] += 0.5
    col_c = np.concatenate([colours, _faded_weights(q, f_col)], axis=-1)
    tab_c = np.concatenate([col_c.reshape(n * w, 8), planes["c"]], dtype=f32)  # ... rounded
    # A wall's s(u) is constant down its column, so its two s-coordinates s * scale +
    # offset are computed here once per column, into the offsets, with scale 0: a pixel's
    # x * 0 + offset is then that value for any finite x (up to the sign of a zero, which
    # the rounding down to a texel ignores). So every pixel can use x = the plane's s.
    col_a = q.take(_COORD_COLS, axis=-1)                                  # (N, W, 8)
    s32 = hit["s"].astype(f32)[..., None]
    col_a[..., 4::2] = s32 * col_a[..., 0:4:2] + col_a[..., 4::2]
    col_a[..., 0:4:2] = 0.0
    tab_a = np.concatenate([col_a.reshape(n * w, 8), planes["a"]])
    stagger = planes["any_stagger"]
    if stagger:
        tab_s = np.concatenate([q[..., D_STAGGER].reshape(-1), planes["stagger"]])

    # Per-frame factors of the texture coordinates, float32: pixel (v, u) of frame n has
    # x_k = base_k + rf_k(v) cf_k(u) for k = 0, 1, 2: the plane's s and h, the wall's h:
    #   (x, y) + Z_plane(v) (r_x(u), r_y(u)),   altitude + (-y_n(v)) t(u)
    # (-y_n) t added is the same float32 as y_n t subtracted.
    cos, sin = np.cos(poses[:, 2, None]), np.sin(poses[:, 2, None])
    cf = np.empty((3, n, w), f32)
    cf[0], cf[1], cf[2] = cos + xn * sin, sin - xn * cos, hit["t"]     # r(u), t(u)
    rf = np.empty((3, n, h), f32)
    rf[0] = rf[1] = planes["zp_coord"][world]         # Z_plane, 0 at inf (rows of walls)
    rf[2] = -const["yn32"][:, 0]
    base = np.empty((3, n, 1, 1), f32)
    base[0:2, :, 0, 0], base[2, :, 0, 0] = poses[:, :2].T, batch.altitude[world]
    t32, zp32 = cf[2], planes["zp32"][world]                              # (N, W), (N, H)
    if n > 1:   # the table rows of each frame's columns and of its image rows (below)
        col_src = np.arange(n * w).reshape(n, w)
        row_src = (n * w + h * world)[:, None] + np.arange(h)            # (N, H)

    depth = np.empty((n, h, w), f32)
    rgb = np.empty((n, h, w, 3), np.uint8)
    for a, b, r0, r1 in _chunks(n, h, w):
        t, zp = t32[a:b, None, :], zp32[a:b, r0:r1, None]                 # (m, 1, W), (m, R, 1)
        wall = t <= zp                                                    # (m, R, W)
        np.minimum(t, zp, out=depth[a:b, r0:r1])
        if n == 1:          # one frame: one np.where of two cached (H, W) index arrays
            src = np.where(wall, const["col_u"][r0:r1], const["row_src"][r0:r1])
        else:
            # The plane rows broadcast along the columns, then the wall columns copied
            # over the wall pixels (a masked copy from broadcast operands is cheaper than
            # ``np.where`` on full-size index arrays).
            src = np.empty(wall.shape, np.intp)
            np.copyto(src, row_src[a:b, r0:r1, None])
            np.copyto(src, col_src[a:b, None, :], where=wall)
        # From here on every per-pixel array is flat, (P,) with P = m R W pixels (or a
        # stack of such rows): 1-D loops over them stay fast.
        src = src.reshape(-1)
        k_a = tab_a.take(src, axis=0)                                     # (P, 8)
        k_c = tab_c.take(src, axis=0)                                     # (P, 8)
        # Texture coordinates: x = (plane s, h, wall h), then x_1 = the pixel's h.
        x = np.multiply(rf[:, a:b, r0:r1, None], cf[:, a:b, None, :])      # (3, m, R, W)
        x += base[:, a:b]
        np.copyto(x[1], x[2], where=wall)      # walls: their h (masked copy: cheaper
        #                                        than np.where, which writes every pixel)
        # The four lattice coordinates (2, 2, P) = (s, h) * scales + offsets, in two
        # calls: the gathered table's columns are read as (4, P) strided views.
        coords = np.empty((2, 2, wall.size), f32)
        np.multiply(x[:2].reshape(1, 2, -1), k_a[:, :4].T.reshape(2, 2, -1), out=coords)
        coords += k_a[:, 4:].T.reshape(2, 2, -1)
        p = pattern_from_coords(coords, k_c[:, _C_AMP].T,
                                tab_s.take(src) if stagger else None)
        # colour = shade * gain * 255 (c0 + (c1 - c0) p) lies in [0, 255] for p in [0, 1];
        # the cast to uint8 truncates (the + 1/2 in the table makes it round). The three
        # channels at once, as (3, P) views of the gathered table and of the image.
        colour = np.multiply(k_c[:, 3:6].T, p, out=np.empty((3, wall.size), f32))
        np.add(colour, k_c[:, 0:3].T, out=rgb[a:b, r0:r1].reshape(-1, 3).T, casting="unsafe")
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
