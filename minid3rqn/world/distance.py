"""Clearance: the distance from points to the nearest obstacle surface, vectorized.

For a point p the signed distance to one obstacle is

    circle (c, r):      |p - c| - r
    wall a -> b:        |p - a - t (b - a)|,  t = clip((p - a).(b - a) / |b - a|^2, 0, 1)
    convex polygon:     +min over edges of the edge distance if p is outside,
                        -min over edges                       if p is inside,

negative inside solid shapes, and ``nearest_distance`` is the minimum over obstacles.
These are pymunk's own formulas (``Space.point_query_nearest(...).distance`` for
radius-0 shapes); tests/test_world.py checks them against pymunk, one point at a time.

The oracle planner samples clearance at thousands of points per step, so it reads a
precomputed ``ClearanceField`` instead: the signed distance on a regular grid, made
negative outside the flyable region, interpolated bilinearly.
"""
from __future__ import annotations

import numpy as np

from .kinematics import ACTION_INTERVAL, ACTIONS, SAFE_DISTANCE, plan_paths
from .scene import Scene, SceneBatch

_CHUNK = 4096   # points per block when a query is large (bounds the temporaries)


def _segment_distance(px, py, ax, ay, bx, by):
    """Point-to-segment distance; points (..., M, 1), segments (..., 1, S) -> (..., M, S),
    plus the 2D cross product (b - a) x (p - a) (positive: p on the left of a -> b)."""
    ex, ey = bx - ax, by - ay
    dx, dy = px - ax, py - ay
    inv = 1.0 / np.maximum(ex * ex + ey * ey, 1e-300)
    t = np.clip((dx * ex + dy * ey) * inv, 0.0, 1.0)
    qx, qy = dx - t * ex, dy - t * ey
    return np.sqrt(qx * qx + qy * qy), ex * dy - ey * dx


def _signed_distance(circ_c, circ_r, wall_a, wall_b, poly, xy):
    """Core of the distance queries. Leading world axis N on every argument:
    circ_c (N, C, 2), circ_r (N, C), wall_a/b (N, S, 2), poly (N, P, V, 2), xy (N, M, 2)
    -> (N, M) float64."""
    px, py = xy[..., 0, None], xy[..., 1, None]                       # (N, M, 1)
    best = np.full(xy.shape[:-1], np.inf)
    if circ_c.shape[1]:
        d = np.hypot(px - circ_c[:, None, :, 0], py - circ_c[:, None, :, 1]) - circ_r[:, None, :]
        best = np.minimum(best, d.min(-1))
    if wall_a.shape[1]:
        d, _ = _segment_distance(px, py, wall_a[:, None, :, 0], wall_a[:, None, :, 1],
                                 wall_b[:, None, :, 0], wall_b[:, None, :, 1])
        best = np.minimum(best, d.min(-1))
    if poly.shape[1]:
        n, p_count, v_count, _ = poly.shape
        a = poly.reshape(n, 1, p_count * v_count, 2)
        b = np.roll(poly, -1, axis=2).reshape(n, 1, p_count * v_count, 2)
        d, cross = _segment_distance(px, py, a[..., 0], a[..., 1], b[..., 0], b[..., 1])
        shape = d.shape[:2] + (p_count, v_count)
        d, cross = d.reshape(shape).min(-1), cross.reshape(shape)
        outside = np.any(cross < 0, axis=-1)
        best = np.minimum(best, np.where(outside, d, -d).min(-1))
    return best


def _check_xy(xy, name):
    arr = np.asarray(xy, dtype=np.float64)
    if arr.ndim < 1 or arr.shape[-1] != 2:
        raise ValueError(f"{name}: xy must have shape (..., 2); got shape {arr.shape}")
    return arr


def _check_batch_xy(batch, xy, name):
    """A SceneBatch and points (N, M, 2), one point set per world; else a clear error."""
    if not isinstance(batch, SceneBatch):
        raise TypeError(f"{name}: batch must be a SceneBatch; got {type(batch).__name__}")
    xy = _check_xy(xy, name)
    if xy.ndim != 3 or xy.shape[0] != len(batch):
        raise ValueError(f"{name}: xy must be (N={len(batch)}, M, 2); got shape {xy.shape}")
    return xy


def nearest_distance(scene: Scene, xy) -> np.ndarray:
    """Signed distance from each point to the nearest obstacle of ``scene``.

    xy (..., 2) world metres -> (...) float64 (a 0-d array for one point).
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"nearest_distance: scene must be a Scene; got {type(scene).__name__}")
    xy = _check_xy(xy, "nearest_distance")
    flat = xy.reshape(-1, 2)
    out = np.empty(len(flat))
    args = (scene.circle_centres[None], scene.circle_radii[None], scene.wall_a[None],
            scene.wall_b[None], scene.poly_verts[None])
    for k in range(0, len(flat), _CHUNK):
        out[k:k + _CHUNK] = _signed_distance(*args, flat[None, k:k + _CHUNK])[0]
    return out.reshape(xy.shape[:-1])


def nearest_distance_batch(batch: SceneBatch, xy) -> np.ndarray:
    """Signed distances in N worlds at once: xy (N, M, 2), point set m in world n ->
    (N, M) float64."""
    xy = _check_batch_xy(batch, xy, "nearest_distance_batch")
    return _signed_distance(batch.circ_c, batch.circ_r, batch.wall_a, batch.wall_b,
                            batch.poly, xy)


KINDS = ("round", "polygon", "wall")      # circles; boxes and buildings; walls


def nearest_distance_by_kind(batch: SceneBatch, xy) -> np.ndarray:
    """Like ``nearest_distance_batch``, one distance per kind of obstacle: xy (N, M, 2)
    -> (N, M, 3), the signed distance to the nearest circle, polygon and wall
    (``KINDS``; a world without one kind reads a very large distance there). The
    minimum over the last axis is ``nearest_distance_batch``."""
    xy = _check_batch_xy(batch, xy, "nearest_distance_by_kind")
    c, r, a, b, poly = batch.circ_c, batch.circ_r, batch.wall_a, batch.wall_b, batch.poly
    no_c, no_r, no_s, no_p = c[:, :0], r[:, :0], a[:, :0], poly[:, :0]
    return np.stack([_signed_distance(c, r, no_s, no_s, no_p, xy),
                     _signed_distance(no_c, no_r, no_s, no_s, poly, xy),
                     _signed_distance(no_c, no_r, a, b, no_p, xy)], axis=-1)


class ClearanceField:
    """The signed clearance of a scene on a grid, capped, read back bilinearly.

    value(x, y) = min(nearest_distance, cap) inside the flyable region and
    -min(|nearest_distance|, cap) outside it, on the grid x0 + i h, y0 + j h covering the
    scene bounds plus one cell; points off the grid read -1. Built by splatting: each
    obstacle updates only the cells within ``cap`` of its bounding box, so the cost grows
    with the obstacles' size, not with the number of obstacles times the grid.
    """

    def __init__(self, scene: Scene, resolution: float = 0.25, cap: float = 3.0):
        if not resolution > 0 or not cap > 0:
            raise ValueError(f"ClearanceField: resolution and cap must be > 0; got "
                             f"{resolution}, {cap}")
        self.resolution, self.cap = float(resolution), float(cap)
        lo = scene.bounds[:2] - resolution
        shape = np.ceil((scene.bounds[2:] + resolution - lo) / resolution).astype(int) + 1
        self.origin = lo
        xs = lo[0] + resolution * np.arange(shape[0])
        ys = lo[1] + resolution * np.arange(shape[1])
        d = np.full(tuple(shape), self.cap)

        def splat(box_lo, box_hi, distance_fn):
            i0, j0 = np.maximum(np.floor((box_lo - self.cap - lo) / resolution).astype(int), 0)
            i1, j1 = np.minimum(np.ceil((box_hi + self.cap - lo) / resolution).astype(int) + 1,
                                shape)
            gx, gy = np.meshgrid(xs[i0:i1], ys[j0:j1], indexing="ij")
            window = d[i0:i1, j0:j1]
            np.minimum(window, distance_fn(np.stack([gx, gy], -1)), out=window)

        empty = np.zeros((1, 0, 2))
        for c, r in zip(scene.circle_centres, scene.circle_radii):
            splat(c - r, c + r, lambda g: np.hypot(g[..., 0] - c[0], g[..., 1] - c[1]) - r)
        for a, b in zip(scene.wall_a, scene.wall_b):
            splat(np.minimum(a, b), np.maximum(a, b), lambda g: _signed_distance(
                empty, np.zeros((1, 0)), a[None, None], b[None, None], np.zeros((1, 0, 3, 2)),
                g.reshape(1, -1, 2))[0].reshape(g.shape[:-1]))
        for v in scene.poly_verts:
            splat(v.min(0), v.max(0), lambda g: _signed_distance(
                empty, np.zeros((1, 0)), empty, empty, v[None, None],
                g.reshape(1, -1, 2))[0].reshape(g.shape[:-1]))
        grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1)
        self.values = np.where(scene.in_region(grid), d, -np.abs(d)).astype(np.float32)


def sample_fields(values, origins, resolution: float, xy) -> np.ndarray:
    """Bilinear lookup in N stacked fields: values (N, Gx, Gy), origins (N, 2),
    xy (N, M, 2) -> (N, M) float32; points off a grid read -1."""
    n, gx, gy = values.shape
    g = (xy - origins[:, None, :]) / resolution
    i0f, j0f = np.floor(g[..., 0]), np.floor(g[..., 1])
    tx, ty = (g[..., 0] - i0f).astype(np.float32), (g[..., 1] - j0f).astype(np.float32)
    i0, j0 = i0f.astype(np.int64), j0f.astype(np.int64)
    on = (i0 >= 0) & (i0 < gx - 1) & (j0 >= 0) & (j0 < gy - 1)
    i0, j0 = np.where(on, i0, 0), np.where(on, j0, 0)
    flat = values.reshape(n, -1)
    base = np.arange(n)[:, None] * (gx * gy) + i0 * gy + j0
    f = flat.ravel()
    v00, v01 = f[base], f[base + 1]
    v10, v11 = f[base + gy], f[base + gy + 1]
    out = (v00 + (v01 - v00) * ty) * (1 - tx) + (v10 + (v11 - v10) * ty) * tx
    return np.where(on, out, np.float32(-1.0))


def clearance_field(scene: Scene, resolution: float = 0.25) -> ClearanceField:
    """The scene's ClearanceField, computed once and cached on the scene."""
    key = ("field", float(resolution))
    if key not in scene._cache:
        scene._cache[key] = ClearanceField(scene, resolution)
    return scene._cache[key]


_PLANS = {}


def _cached_plans(actions: np.ndarray, dt: float):
    key = (actions.tobytes(), dt)
    if key not in _PLANS:
        _PLANS[key] = plan_paths(actions, dt)
    return _PLANS[key]


def sample_start_pose(scene: Scene, rng: np.random.Generator, actions=ACTIONS,
                      dt: float = ACTION_INTERVAL, safe_distance: float = SAFE_DISTANCE,
                      max_rounds: int = 200) -> np.ndarray:
    """A random free start pose (x, y, yaw) as a (3,) float64 array.

    Candidates are drawn uniformly over the scene bounds with a uniform heading and
    accepted, in order, when
    - the position lies in the flyable region with clearance >= ``scene.start_clearance``,
    - the straight path of ``scene.start_free_ahead`` metres ahead keeps clearance
      >= ``scene.start_clearance / 2``, and
    - there is a way out: some plan of ``kinematics.plan_paths`` (15 steps, 12 m) keeps
      clearance >= ``safe_distance`` + 0.3 m and stays in the flyable region.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"sample_start_pose: rng must be a numpy Generator; got "
                        f"{type(rng).__name__}")
    lo, hi = scene.bounds[:2], scene.bounds[2:]
    ahead = np.arange(1, int(np.ceil(scene.start_free_ahead / 0.25)) + 1) * 0.25
    per_step, plans = _cached_plans(np.asarray(actions, np.float64), float(dt))
    first = per_step[:, 0]
    groups = [plans[first == a, :, :2] for a in np.argsort(np.abs(np.asarray(actions)[:, 1]))]
    for _ in range(max_rounds):
        xy = rng.uniform(lo, hi, size=(64, 2))
        yaw = rng.uniform(-np.pi, np.pi, size=64)
        ok = scene.in_region(xy)
        ok[ok] &= nearest_distance(scene, xy[ok]) >= scene.start_clearance
        heading = np.stack([np.cos(yaw), np.sin(yaw)], -1)
        path = xy[:, None, :] + ahead[None, :, None] * heading[:, None, :]
        ok[ok] &= nearest_distance(scene, path[ok]).min(-1) >= 0.5 * scene.start_clearance
        for k in np.flatnonzero(ok):
            c, s = heading[k]
            for rel in groups:                     # straightest first action first
                pts = xy[k] + rel @ np.array([[c, s], [-s, c]])
                clear = nearest_distance(scene, pts).min(-1)
                best = int(np.argmax(clear))
                if clear[best] >= safe_distance + 0.3 and scene.in_region(pts[best]).all():
                    return np.array([xy[k, 0], xy[k, 1], yaw[k]])
    raise RuntimeError(f"sample_start_pose: no free start pose found in scene {scene.name!r} "
                       f"(seed {scene.seed}) after {max_rounds * 64} candidates")
