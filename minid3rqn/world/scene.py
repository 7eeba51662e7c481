"""Scenes: static obstacles as a pymunk Space and as flat NumPy arrays of the same geometry.

Obstacles are vertical prisms from the floor (z = 0) to the ceiling (z = ``ceiling``):

- circles (pillars, trees): centre (2,) and radius;
- convex polygons (boxes, blocks): vertices (V, 2), counter-clockwise;
- walls: thin segments a -> b, seen from both sides.

Each obstacle carries an appearance id, a row of the scene's appearance table
(``textures.py``); rows 0 and 1 are the floor and the ceiling. Texture coordinate s along
a wall or polygon edge is ``u0 + arc length from the edge's start``, with u0 the length
of the outline before the edge, so textures run on continuously around corners.

The renderer and the distance code read the flat arrays (``Scene.render_segments()``,
``SceneBatch``); pymunk answers the same questions one at a time and serves as the
reference in the tests. ``SceneBatch`` pads the arrays of N scenes to common sizes so
one NumPy expression handles all of them: padded circles and walls sit at FAR metres
(never nearest), padded segments are degenerate (never hit).
"""
from __future__ import annotations

import copy

from dataclasses import dataclass, field

import numpy as np
import pymunk

from .textures import N_DERIVED, N_PARAMS, derived_table

FAR = 1.0e6   # metres; where padding geometry is parked


@dataclass(eq=False)
class Scene:
    """One world. Arrays are float64 (positions in metres) or int64 (appearance ids).

    Attributes:
        name, seed: the scenario and the seed it was generated from.
        bounds: (4,) xmin, ymin, xmax, ymax enclosing all geometry.
        altitude: camera height above the floor (m); ceiling: ceiling height (m).
        circle_centres (C, 2), circle_radii (C,), circle_app (C,).
        wall_a (S, 2), wall_b (S, 2), wall_app (S,), wall_u0 (S,).
        poly_verts (P, V, 2) counter-clockwise; polygons with fewer vertices repeat their
            last vertex. poly_app (P,), poly_u0 (P, V): texture offset of each edge.
        appearances (A, N_PARAMS) float32 appearance table.
        region_outer (K, 2): outline of the flyable region; region_holes: outlines of
            solid areas inside it that are closed off by walls (start poses avoid both).
        start_clearance: minimum obstacle distance of a start position (m).
        start_free_ahead: length (m) of the straight path ahead of a start pose that must
            keep ``start_clearance / 2`` of clearance.
        space: pymunk Space holding the same obstacles as static shapes.
    """

    name: str
    seed: int
    bounds: np.ndarray
    altitude: float
    ceiling: float
    circle_centres: np.ndarray
    circle_radii: np.ndarray
    circle_app: np.ndarray
    wall_a: np.ndarray
    wall_b: np.ndarray
    wall_app: np.ndarray
    wall_u0: np.ndarray
    poly_verts: np.ndarray
    poly_app: np.ndarray
    poly_u0: np.ndarray
    appearances: np.ndarray
    region_outer: np.ndarray
    region_holes: tuple = ()
    start_clearance: float = 1.5
    start_free_ahead: float = 4.0
    space: pymunk.Space = field(default=None, repr=False)
    _cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        if self.space is None:
            self.space = build_space(self)

    def render_segments(self):
        """All straight surfaces: walls then polygon edges (degenerate edges dropped).

        Returns (a (E, 2), b (E, 2), app (E,), u0 (E,)).
        """
        if "segments" not in self._cache:
            pa = self.poly_verts
            pb = np.roll(pa, -1, axis=1)
            keep = np.linalg.norm(pb - pa, axis=-1) > 0
            app = np.broadcast_to(self.poly_app[:, None], keep.shape)
            self._cache["segments"] = (
                np.concatenate([self.wall_a, pa[keep]]), np.concatenate([self.wall_b, pb[keep]]),
                np.concatenate([self.wall_app, app[keep]]),
                np.concatenate([self.wall_u0, self.poly_u0[keep]]))
        return self._cache["segments"]

    def in_region(self, xy) -> np.ndarray:
        """(..., 2) -> (...) bool: inside ``region_outer`` and outside every hole."""
        xy = np.asarray(xy, dtype=np.float64)
        inside = point_in_polygon(xy, self.region_outer)
        for hole in self.region_holes:
            inside &= ~point_in_polygon(xy, hole)
        return inside

    def batch(self) -> "SceneBatch":
        """This scene as a SceneBatch of one (cached)."""
        if "batch" not in self._cache:
            self._cache["batch"] = SceneBatch([self])
        return self._cache["batch"]


def point_in_polygon(xy, polygon) -> np.ndarray:
    """Crossing-number test: (..., 2) points, (K, 2) closed outline -> (...) bool."""
    xy = np.asarray(xy, dtype=np.float64)
    a = np.asarray(polygon, dtype=np.float64)
    b = np.roll(a, -1, axis=0)
    x, y = xy[..., None, 0], xy[..., None, 1]
    straddles = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return np.count_nonzero(straddles & (x < x_cross), axis=-1) % 2 == 1


def build_space(scene: Scene) -> pymunk.Space:
    """A pymunk Space with one static shape per obstacle (radius-0 segments and polys)."""
    space = pymunk.Space()
    body = space.static_body
    shapes = [pymunk.Circle(body, float(r), offset=(float(c[0]), float(c[1])))
              for c, r in zip(scene.circle_centres, scene.circle_radii)]
    shapes += [pymunk.Segment(body, tuple(map(float, a)), tuple(map(float, b)), 0.0)
               for a, b in zip(scene.wall_a, scene.wall_b)]
    for verts in scene.poly_verts:
        unique = verts[np.r_[True, np.any(np.diff(verts, axis=0) != 0, axis=1)]]
        shapes.append(pymunk.Poly(body, [tuple(map(float, v)) for v in unique], radius=0.0))
    if shapes:
        space.add(*shapes)
    return space


class SceneBuilder:
    """Collects obstacles and appearances, then freezes them into a ``Scene``.

    Appearance rows 0 and 1 (floor, ceiling) are given to the constructor; every other
    appearance is added with ``add_appearance`` and referred to by the id it returns.
    """

    def __init__(self, floor: np.ndarray, ceiling: np.ndarray):
        self._apps = [np.asarray(floor, np.float32), np.asarray(ceiling, np.float32)]
        self._circles, self._walls, self._polys = [], [], []

    def add_appearance(self, row) -> int:
        row = np.asarray(row, np.float32)
        if row.shape != (N_PARAMS,):
            raise ValueError(f"add_appearance: row must have shape ({N_PARAMS},); got {row.shape}")
        self._apps.append(row)
        return len(self._apps) - 1

    def add_circle(self, centre, radius: float, app: int):
        if not radius > 0:
            raise ValueError(f"add_circle: radius must be > 0; got {radius}")
        self._circles.append((np.asarray(centre, float), float(radius), int(app)))

    def add_polygon(self, verts, app: int):
        """A convex polygon (vertices in any winding; stored counter-clockwise)."""
        v = np.asarray(verts, float)
        if v.ndim != 2 or v.shape[1] != 2 or len(v) < 3:
            raise ValueError(f"add_polygon: verts must be (V >= 3, 2); got shape {v.shape}")
        area2 = np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])
        if area2 < 0:
            v = v[::-1]
        self._polys.append((v, int(app)))

    def add_box(self, centre, size, angle: float, app: int):
        """A rectangle of ``size`` = (length, width) metres rotated by ``angle`` radians."""
        c, s = np.cos(angle), np.sin(angle)
        hx, hy = 0.5 * size[0], 0.5 * size[1]
        local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        self.add_polygon(np.asarray(centre, float) + local @ np.array([[c, s], [-s, c]]), app)

    def add_polyline(self, points, app, closed: bool = False):
        """Walls along consecutive points; ``app`` is one id or one per segment."""
        p = np.asarray(points, float)
        a, b = (p, np.roll(p, -1, axis=0)) if closed else (p[:-1], p[1:])
        apps = np.broadcast_to(np.asarray(app, int), (len(a),))
        lengths = np.linalg.norm(b - a, axis=1)
        u0 = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
        for k in range(len(a)):
            if lengths[k] > 0:
                self._walls.append((a[k], b[k], int(apps[k]), u0[k]))

    def build(self, name: str, seed: int, altitude: float, ceiling: float, region_outer,
              region_holes=(), start_clearance: float = 1.5,
              start_free_ahead: float = 4.0) -> Scene:
        cc = np.array([c for c, _, _ in self._circles]).reshape(-1, 2)
        walls_a = np.array([w[0] for w in self._walls]).reshape(-1, 2)
        walls_b = np.array([w[1] for w in self._walls]).reshape(-1, 2)
        v_max = max([len(v) for v, _ in self._polys] + [3])
        verts = np.zeros((len(self._polys), v_max, 2))
        u0 = np.zeros((len(self._polys), v_max))
        for k, (v, _) in enumerate(self._polys):
            verts[k, :len(v)] = v
            verts[k, len(v):] = v[-1]
            edge = np.linalg.norm(np.roll(verts[k], -1, axis=0) - verts[k], axis=1)
            u0[k] = np.concatenate([[0.0], np.cumsum(edge)[:-1]])
        everything = np.concatenate([cc, walls_a, walls_b, verts.reshape(-1, 2),
                                     np.asarray(region_outer, float)])
        pad = np.concatenate([np.array([r for _, r, _ in self._circles]), [0.0]]).max()
        bounds = np.r_[everything.min(0) - pad, everything.max(0) + pad]
        return Scene(
            name=name, seed=int(seed), bounds=bounds, altitude=float(altitude),
            ceiling=float(ceiling), circle_centres=cc,
            circle_radii=np.array([r for _, r, _ in self._circles], float),
            circle_app=np.array([a for _, _, a in self._circles], np.int64),
            wall_a=walls_a, wall_b=walls_b,
            wall_app=np.array([w[2] for w in self._walls], np.int64),
            wall_u0=np.array([w[3] for w in self._walls], float),
            poly_verts=verts, poly_app=np.array([a for _, a in self._polys], np.int64),
            poly_u0=u0, appearances=np.stack(self._apps),
            region_outer=np.asarray(region_outer, float),
            region_holes=tuple(np.asarray(h, float) for h in region_holes),
            start_clearance=float(start_clearance), start_free_ahead=float(start_free_ahead))


def _far_polygon(n_verts: int) -> np.ndarray:
    """A unit triangle parked at FAR, padded to ``n_verts`` by repeating its last vertex."""
    tri = FAR + np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    return np.concatenate([tri, np.repeat(tri[-1:], max(n_verts - 3, 0), 0)])[:max(n_verts, 3)]


class SceneBatch:
    """N scenes with their obstacle arrays padded to common sizes, for batched queries.

    Arrays (n = world index):
        circ_c (N, C, 2), circ_r (N, C), circ_app (N, C)     circles
        seg_app (N, E), seg_u0 (N, E), seg_len (N, E)         render segments
        wall_a, wall_b (N, S, 2)                               walls (for distances)
        poly (N, P, V, 2)                                      polygons (for distances)
        points (N, 2, 2E + C)                                  x and y rows of the
            segment ends A, the ends B and the circle centres (the renderer turns them
            into camera coordinates in one pass)
        seg_consts (N, E, 3)                                   length, u0, app (float)
        circ_r2 (N, C), circ_inf (N, C)                        R^2; 0 (inf for padding)
        tex (N, A, N_DERIVED) float32                          ``derived_table`` of the
                                                               appearance tables
        altitude (N,)
    ``set(n, scene)`` swaps one world in place (the arrays grow if it needs more room).
    """

    def __init__(self, scenes):
        scenes = list(scenes)
        if not scenes or not all(isinstance(s, Scene) for s in scenes):
            raise TypeError("SceneBatch: scenes must be a non-empty sequence of Scene")
        self.scenes = scenes
        self._cache = {}          # the renderer's per-camera constants of these worlds
        self._allocate(len(scenes), *np.max([self._sizes(s) for s in scenes], axis=0))
        for n, s in enumerate(scenes):
            self._write(n, s)

    def __len__(self) -> int:
        return len(self.scenes)

    @staticmethod
    def _sizes(scene: Scene):
        a, _, _, _ = scene.render_segments()
        return (len(scene.circle_radii), len(a), len(scene.wall_app), len(scene.poly_app),
                scene.poly_verts.shape[1], len(scene.appearances))

    def _allocate(self, n, C, E, S, P, V, A):
        # At least one (padding) slot per kind keeps every reduction non-empty.
        C, E, S, P, V = max(C, 1), max(E, 1), max(S, 1), max(P, 1), max(V, 3)
        self.sizes = (C, E, S, P, V, A)
        self.circ_c = np.full((n, C, 2), FAR)
        self.circ_r = np.zeros((n, C))
        self.circ_app = np.zeros((n, C), np.int64)
        self.seg_app = np.zeros((n, E), np.int64)
        self.seg_u0 = np.zeros((n, E))
        self.wall_a = np.full((n, S, 2), FAR)
        self.wall_b = np.full((n, S, 2), FAR)
        self.poly = np.broadcast_to(_far_polygon(V), (n, P, V, 2)).copy()
        self.seg_len = np.zeros((n, E))
        self.points = np.zeros((n, 2, 2 * E + C))
        self.seg_consts = np.zeros((n, E, 3))
        self.circ_r2 = np.zeros((n, C))
        self.circ_inf = np.zeros((n, C))
        self.tex = np.zeros((n, A, N_DERIVED), np.float32)
        self.altitude = np.zeros(n)

    def _write(self, n: int, scene: Scene):
        C, E, S, P, V, A = self._sizes(scene)
        self.circ_c[n] = FAR
        self.circ_c[n, :C] = scene.circle_centres
        self.circ_r[n] = 0.0
        self.circ_r[n, :C] = scene.circle_radii
        self.circ_app[n] = 0
        self.circ_app[n, :C] = scene.circle_app
        a, b, app, u0 = scene.render_segments()
        ends = np.full((2, self.seg_len.shape[1], 2), FAR)             # A, B; padding FAR
        ends[0, :E], ends[1, :E] = a, b
        self.seg_app[n] = 0
        self.seg_app[n, :E] = app
        self.seg_u0[n] = 0.0
        self.seg_u0[n, :E] = u0
        self.wall_a[n] = FAR
        self.wall_b[n] = FAR
        self.wall_a[n, :S], self.wall_b[n, :S] = scene.wall_a, scene.wall_b
        self.poly[n] = _far_polygon(self.poly.shape[2])
        self.poly[n, :P, :V] = scene.poly_verts
        self.poly[n, :P, V:] = scene.poly_verts[:, -1:]
        self.seg_len[n] = np.hypot(*(ends[1] - ends[0]).T)
        self.points[n] = np.concatenate([ends[0], ends[1], self.circ_c[n]]).T
        self.seg_consts[n] = np.stack([self.seg_len[n], self.seg_u0[n], self.seg_app[n]], -1)
        self.circ_r2[n] = self.circ_r[n] * self.circ_r[n]
        self.circ_inf[n] = np.where(self.circ_r[n] > 0, 0.0, np.inf)
        self.tex[n] = 0.0
        self.tex[n, :A] = derived_table(scene.appearances)
        self.altitude[n] = scene.altitude
        self.scenes[n] = scene

    def subset(self, idx) -> "SceneBatch":
        """The worlds ``idx`` as a new SceneBatch sharing nothing mutable with this one:
        rows of the per-world arrays, and an empty renderer cache (a shared cache would
        hand one batch's per-world tables to the other)."""
        idx = np.asarray(idx, dtype=np.int64)
        sub = copy.copy(self)
        n = len(self.scenes)
        for name, value in vars(self).items():
            if isinstance(value, np.ndarray) and value.ndim >= 1 and len(value) == n:
                setattr(sub, name, value[idx])
        sub.scenes = [self.scenes[k] for k in idx]
        sub._cache = {}
        return sub

    def set(self, n: int, scene: Scene):
        """Replace world ``n`` by ``scene``, growing the padded arrays when needed."""
        if not isinstance(scene, Scene):
            raise TypeError(f"SceneBatch.set: scene must be a Scene; got {type(scene).__name__}")
        need = np.maximum(self._sizes(scene), self.sizes)
        if np.any(need > self.sizes):
            self._allocate(len(self.scenes), *need)
            for k, s in enumerate(self.scenes):
                self._write(k, s)
        self._write(n, scene)
