"""The four scenarios, each a random world generated from a seed.

- ``basic`` (the paper's training world): a square walled arena crowded with pillars and
  boxes of varied size and colour.
- ``channel`` (Env-1, narrow channel): a closed corridor, 4-5 m wide, that bends to and
  fro along a wobbly loop; brick and concrete walls.
- ``intersections`` (Env-2): a grid of streets between rectangular blocks, with
  crossings; building facades.
- ``corners`` (Env-3): a closed corridor with sharp L-corners and zigzags, running round
  a random polyomino; tiled walls.

All are closed (every camera ray hits a wall) and at most about 40 m across, so flying
blind fails (a flight is 50 x 0.8 m = 40 m); the gaps, corridor widths and corners
leave room for a pilot who looks ahead and turns on a 4 m radius (2 m/s at 0.5 rad/s).
``make_scene(name, seed)`` builds one from the scenario's parameters (``DEFAULTS``).
"""
from __future__ import annotations

import numpy as np

from .scene import Scene, SceneBuilder
from .textures import (LATTICE_SIZE, hsv_to_rgb, make_appearance, random_appearance)

SCENARIOS = ("basic", "channel", "intersections", "corners")

# Pillars inside the corridors and streets of the transfer scenarios: one every
# ``pillar_spacing`` metres along the centre line, ``pillar_offset`` metres to a random
# side of it, so that flying down the middle hits them and the wide side stays open
# (>= 2 m free for a 4.2 m corridor).
PILLARS = dict(pillar_radius=(0.25, 0.45), pillar_offset=(0.5, 1.0),
               pillar_spacing=(8.0, 12.0))

DEFAULTS = {
    "basic": dict(size=(22.0, 26.0), n_obstacles=(11, 15), pillar_radius=(0.25, 0.8),
                  box_size=(0.6, 2.6), min_gap=3.0, wall_margin=3.0, altitude=1.0,
                  ceiling=3.0, start_clearance=1.5, start_free_ahead=4.0),
    "channel": dict(radius=(10.0, 12.0), wobble=(0.12, 0.22), width=(4.2, 5.0),
                    n_vertices=28, altitude=1.0, ceiling=3.0, start_clearance=1.4,
                    start_free_ahead=4.0, **PILLARS),
    "intersections": dict(n_blocks=(3, 3), block_size=(4.0, 6.5), street=(4.6, 5.6),
                          altitude=1.0, ceiling=3.0, start_clearance=1.5,
                          start_free_ahead=4.0, **PILLARS),
    "corners": dict(grid=(5, 5), n_cells=(9, 14), cell=7.0, width=(4.6, 5.2),
                    altitude=1.0, ceiling=3.0, start_clearance=1.5, start_free_ahead=4.0,
                    **PILLARS),
}


def make_scene(name: str, seed: int = 0) -> Scene:
    """Generate scenario ``name`` from ``seed`` (its parameters: ``DEFAULTS[name]``); the
    same (name, seed) give the same world. An unknown name raises ValueError."""
    if name not in SCENARIOS:
        raise ValueError(f"make_scene: name must be one of {SCENARIOS}; got {name!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f"make_scene: seed must be an int; got {type(seed).__name__}")
    rng = np.random.default_rng([int(seed), SCENARIOS.index(name)])
    return _GENERATORS[name](rng, int(seed), **DEFAULTS[name])


def _uniform(rng, lohi):
    lo, hi = lohi
    return float(rng.uniform(lo, hi)) if hi > lo else float(lo)


def _integers(rng, lohi):
    lo, hi = lohi
    return int(rng.integers(lo, hi + 1))


def _rect(x0, y0, x1, y1):
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)


def _panel_walls(builder, rng, outline, make_app, panel=(3.0, 6.0)):
    """Closed wall along ``outline``, cut into panels of random length, each with its own
    appearance (texture coordinates continue across panels)."""
    pts = [outline[0]]
    a_ids = []
    for a, b in zip(outline, np.roll(outline, -1, axis=0)):
        length = np.linalg.norm(b - a)
        cuts = [0.0]
        while cuts[-1] < length:
            cuts.append(cuts[-1] + rng.uniform(*panel))
        cuts[-1] = length
        if len(cuts) > 2 and cuts[-1] - cuts[-2] < 1.0:
            cuts.pop(-2)
        for c in cuts[1:]:
            pts.append(a + (b - a) * c / length)
            a_ids.append(make_app())
    builder.add_polyline(np.array(pts[:-1]), np.array(a_ids), closed=True)


# ---------------------------------------------------------------------------------------
# basic: walled arena with pillars and boxes.

def _basic(rng, seed, size, n_obstacles, pillar_radius, box_size, min_gap, wall_margin,
           altitude, ceiling, start_clearance, start_free_ahead):
    floor = make_appearance((0.30, 0.28, 0.25), (0.66, 0.62, 0.55), su=1.0, sv=1.0,
                            w_block=0.75, noise_scale=0.7, offset=rng.integers(0, 64, 2))
    ceil = make_appearance((0.86, 0.88, 0.92), (0.50, 0.55, 0.62), su=1.2, sv=1.2,
                           w_block=0.7, noise_scale=1.5, offset=rng.integers(0, 64, 2), gain=0.9)
    b = SceneBuilder(floor, ceil)
    lx, ly = _uniform(rng, size), _uniform(rng, size)
    arena = _rect(0, 0, lx, ly)
    _panel_walls(b, rng, arena, lambda: b.add_appearance(random_appearance(
        rng, hue_range=(0.05, 0.15), sat=(0.1, 0.3), val=(0.55, 0.8), size=(0.6, 1.2))))
    # (arena walls are seen from afar: larger cells keep their texture above the
    # anti-aliasing fade at 10 m and more)
    # Dart throwing: 400 candidate obstacles, accepted in order unless they come within
    # min_gap of an accepted one, until n are placed.
    n, m = _integers(rng, n_obstacles), 400
    is_pillar = rng.random(m) < 0.5
    radius = rng.uniform(*pillar_radius, m)
    sides = rng.uniform(*box_size, (m, 2))
    angle = rng.uniform(0, np.pi, m)
    reach = np.where(is_pillar, radius, 0.5 * np.hypot(sides[:, 0], sides[:, 1]))
    lo = wall_margin + reach[:, None]
    centre = lo + rng.random((m, 2)) * (np.array([lx, ly]) - 2 * lo)
    conflict = (np.linalg.norm(centre[:, None] - centre[None], axis=-1)
                < reach[:, None] + reach[None] + min_gap)
    accepted = np.zeros(m, bool)
    for i in range(m):
        if accepted.sum() == n:
            break
        accepted[i] = not np.any(conflict[i] & accepted)
    for i in np.flatnonzero(accepted):
        app = b.add_appearance(random_appearance(rng))
        if is_pillar[i]:
            b.add_circle(centre[i], radius[i], _round_circle(b, app, radius[i]))
        else:
            b.add_box(centre[i], sides[i], angle[i], app)
    return b.build("basic", seed, altitude, ceiling, arena, (), start_clearance,
                   start_free_ahead)


def _round_circle(builder, app, radius):
    """Make a pillar's block pattern wrap seamlessly: su = 2 pi R / round(2 pi R / su)."""
    from .textures import SU
    row = builder._apps[app]
    circ = 2 * np.pi * radius
    row[SU] = circ / max(1, round(circ / min(float(row[SU]), circ)))
    return app


# ---------------------------------------------------------------------------------------
# Corridors along a closed centre line: channel and corners.

def _offset_loop(centre, half_width):
    """Mitred offsets of a counter-clockwise closed polygon: (inner, outer) outlines."""
    d_in = centre - np.roll(centre, 1, axis=0)
    d_out = np.roll(centre, -1, axis=0) - centre
    d_in /= np.linalg.norm(d_in, axis=1, keepdims=True)
    d_out /= np.linalg.norm(d_out, axis=1, keepdims=True)
    n_in = np.stack([-d_in[:, 1], d_in[:, 0]], 1)          # left normals (interior side)
    n_out = np.stack([-d_out[:, 1], d_out[:, 0]], 1)
    m = n_in + n_out
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    scale = half_width / np.sum(m * n_in, axis=1, keepdims=True)
    return centre + m * scale, centre - m * scale


def _corridor_scene(rng, seed, name, centre, width, wall_apps, floor, ceil, altitude,
                    ceiling, start_clearance, start_free_ahead, panel, pillars=()):
    b = SceneBuilder(floor, ceil)
    inner, outer = _offset_loop(centre, 0.5 * width)
    _panel_walls(b, rng, outer, lambda: b.add_appearance(wall_apps()), panel)
    _panel_walls(b, rng, inner, lambda: b.add_appearance(wall_apps()), panel)
    for xy, radius, app in pillars:
        b.add_circle(xy, radius, _round_circle(b, b.add_appearance(app), radius))
    return b.build(name, seed, altitude, ceiling, outer, (inner,), start_clearance,
                   start_free_ahead)


def _sharp_turns(loop, degrees: float = 30.0) -> np.ndarray:
    """Vertices of a closed polyline where its direction turns by more than ``degrees``."""
    d_in = loop - np.roll(loop, 1, axis=0)
    d_out = np.roll(loop, -1, axis=0) - loop
    cos = np.sum(d_in * d_out, 1) / (np.linalg.norm(d_in, axis=1) * np.linalg.norm(d_out, axis=1))
    return loop[cos < np.cos(np.radians(degrees))]


def _pillars_along(rng, path, closed, pillar_radius, pillar_offset, pillar_spacing,
                   keep_out=np.zeros((0, 2)), keep_out_radius=5.0):
    """Pillars along a polyline ``path`` (P, 2): [(centre, radius, appearance), ...].

    Every ``pillar_spacing`` metres of arc length (drawn afresh each time), a pillar
    whose centre sits ``pillar_offset`` metres to a random side of the line, unless it
    falls within ``keep_out_radius`` of a ``keep_out`` point (sharp turns and crossings:
    the drone, which turns on a 4 m radius, needs the whole width there).
    """
    pts = np.concatenate([path, path[:1]]) if closed else path
    seg = np.diff(pts, axis=0)
    length = np.linalg.norm(seg, axis=1)
    arc = np.concatenate([[0.0], np.cumsum(length)])
    out, at = [], _uniform(rng, pillar_spacing) * rng.uniform(0.3, 1.0)
    end = arc[-1] - (0.5 * pillar_spacing[0] if closed else 1.0)
    while at < end:
        k = int(np.searchsorted(arc, at, side="right") - 1)
        direction = seg[k] / length[k]
        normal = np.array([-direction[1], direction[0]])
        side = 1.0 if rng.random() < 0.5 else -1.0
        xy = pts[k] + (at - arc[k]) * direction + side * _uniform(rng, pillar_offset) * normal
        radius = _uniform(rng, pillar_radius)
        # saturated, any hue (posts, bollards, trees)
        app = random_appearance(rng, sat=(0.5, 0.9), val=(0.5, 0.9), size=(0.15, 0.3))
        if not np.any(np.linalg.norm(keep_out - xy, axis=1) < keep_out_radius):
            out.append((xy, radius, app))
        at += _uniform(rng, pillar_spacing)
    return out


def _corridor_ok(scene, centre, width):
    """The corridor is clean iff every centre-line point keeps ~half the width of
    clearance from the walls (walls neither cross nor pinch; pillars do not count)."""
    t = np.linspace(0, 1, 8, endpoint=False)[None, :, None]
    pts = (centre[:, None, :] * (1 - t) + np.roll(centre, -1, axis=0)[:, None, :] * t)
    from .distance import _segment_distance
    pts = pts.reshape(-1, 1, 2)
    a, b = scene.wall_a[None], scene.wall_b[None]             # (1, S, 2)
    gap, _ = _segment_distance(pts[..., 0], pts[..., 1], a[..., 0], a[..., 1],
                               b[..., 0], b[..., 1])
    return bool(gap.min() >= 0.42 * width)


def _channel(rng, seed, radius, wobble, width, n_vertices, altitude, ceiling,
             start_clearance, start_free_ahead, pillar_radius, pillar_offset, pillar_spacing):
    floor = make_appearance((0.22, 0.25, 0.22), (0.56, 0.58, 0.48), su=0.8, sv=0.8,
                            w_block=0.6, noise_scale=0.6, offset=rng.integers(0, 64, 2))
    ceil = make_appearance((0.76, 0.72, 0.66), (0.38, 0.35, 0.33), su=0.5, sv=3.0,
                           w_block=0.8, noise_scale=1.0, offset=rng.integers(0, 64, 2), gain=0.85)

    def wall_app():                       # bricks and concrete: warm, low saturation
        c0 = hsv_to_rgb(rng.uniform(0.0, 0.1), rng.uniform(0.3, 0.6), rng.uniform(0.5, 0.8))
        c1 = c0 * rng.uniform(0.45, 0.7)
        su = rng.uniform(0.35, 0.55)
        return make_appearance(c0, c1, su=su, sv=su * 0.45, stagger=0.5,
                               w_block=rng.uniform(0.5, 0.8), noise_scale=rng.uniform(0.6, 1.2),
                               offset=rng.integers(0, LATTICE_SIZE, 2))

    for _ in range(100):
        r0, w = _uniform(rng, radius), _uniform(rng, width)
        theta = np.linspace(0, 2 * np.pi, n_vertices, endpoint=False)
        rr = np.ones_like(theta)
        for k in (2, 3, 4):
            rr += _uniform(rng, wobble) / k * np.cos(k * theta + rng.uniform(0, 2 * np.pi))
        centre = r0 * rr[:, None] * np.stack([np.cos(theta), np.sin(theta)], 1)
        centre += rng.normal(0, 0.3, centre.shape)
        pillars = _pillars_along(rng, centre, True, pillar_radius, pillar_offset,
                                 pillar_spacing)           # gentle bends: no keep-out
        scene = _corridor_scene(rng, seed, "channel", centre, w, wall_app, floor, ceil,
                                altitude, ceiling, start_clearance, start_free_ahead,
                                (2.0, 4.0), pillars)
        if _corridor_ok(scene, centre, w):
            return scene
    raise RuntimeError(f"channel: no clean corridor for seed {seed}")


def _polyomino_outline(cells):
    """Counter-clockwise outline (corners only) of a simply connected set of grid cells,
    or None if the boundary pinches at a vertex."""
    cells = set(cells)
    edges = {}
    for (i, j) in cells:          # cell (i, j) spans [i, i+1] x [j, j+1]; CCW edges
        sides = (((i, j), (i + 1, j), (i, j - 1)),              # (start, end, neighbour)
                 ((i + 1, j), (i + 1, j + 1), (i + 1, j)),
                 ((i + 1, j + 1), (i, j + 1), (i, j + 1)),
                 ((i, j + 1), (i, j), (i - 1, j)))
        for a, b, nb in sides:
            if nb not in cells:
                if a in edges:
                    return None
                edges[a] = b
    start = next(iter(edges))
    loop, v = [start], edges[start]
    while v != start:
        loop.append(v)
        v = edges[v]
    if len(loop) != len(edges):
        return None                                   # a hole: more than one loop
    pts = np.array(loop, float)
    prev, nxt = np.roll(pts, 1, axis=0), np.roll(pts, -1, axis=0)
    d_in, d_out = pts - prev, nxt - pts
    turn = d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0]
    return pts[turn != 0]


def _has_narrow_u_turn(outline) -> bool:
    """True if two successive corners turn the same way with a leg of one cell between
    them: a hairpin around (or into) a one-cell-wide arm, too tight at a 4 m turning
    radius. Zigzags (successive corners turning opposite ways) are fine."""
    prev, nxt = np.roll(outline, 1, axis=0), np.roll(outline, -1, axis=0)
    d_in, d_out = outline - prev, nxt - outline
    turn = np.sign(d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0])
    leg = np.abs(d_out).sum(1)                       # length of the leg after each corner
    return bool(np.any((turn == np.roll(turn, -1)) & (leg < 2)))


def _corners(rng, seed, grid, n_cells, cell, width, altitude, ceiling, start_clearance,
             start_free_ahead, pillar_radius, pillar_offset, pillar_spacing):
    floor = make_appearance((0.18, 0.23, 0.28), (0.50, 0.56, 0.64), su=0.6, sv=0.6,
                            w_block=0.8, noise_scale=0.9, offset=rng.integers(0, 64, 2))
    ceil = make_appearance((0.88, 0.88, 0.82), (0.50, 0.50, 0.46), su=1.5, sv=0.5,
                           w_block=0.75, noise_scale=1.2, offset=rng.integers(0, 64, 2), gain=0.85)

    def wall_app():                       # ceramic tiles: cool hues, square cells
        c0 = hsv_to_rgb(rng.uniform(0.45, 0.75), rng.uniform(0.3, 0.7), rng.uniform(0.55, 0.9))
        c1 = hsv_to_rgb(rng.uniform(0.45, 0.75), rng.uniform(0.1, 0.4), rng.uniform(0.15, 0.4))
        su = rng.uniform(0.3, 0.5)
        return make_appearance(c0, c1, su=su, sv=su, w_block=rng.uniform(0.6, 0.9),
                               noise_scale=rng.uniform(0.5, 1.0),
                               offset=rng.integers(0, LATTICE_SIZE, 2))

    gx, gy = grid
    for _ in range(200):
        target = _integers(rng, n_cells)
        cells = {(int(rng.integers(gx)), int(rng.integers(gy)))}
        while len(cells) < target:
            i, j = list(cells)[int(rng.integers(len(cells)))]
            di, dj = [(1, 0), (-1, 0), (0, 1), (0, -1)][int(rng.integers(4))]
            nb = (i + di, j + dj)
            if 0 <= nb[0] < gx and 0 <= nb[1] < gy:
                cells.add(nb)
        outline = _polyomino_outline(cells)
        if outline is None or _has_narrow_u_turn(outline):
            continue
        w = _uniform(rng, width)
        centre = outline * cell
        pillars = _pillars_along(rng, centre, True, pillar_radius, pillar_offset,
                                 pillar_spacing, keep_out=_sharp_turns(centre),
                                 keep_out_radius=6.5)      # right-angle turns need room
        scene = _corridor_scene(rng, seed, "corners", centre, w, wall_app, floor, ceil,
                                altitude, ceiling, start_clearance, start_free_ahead,
                                (2.0, 3.5), pillars)
        if _corridor_ok(scene, centre, w):
            return scene
    raise RuntimeError(f"corners: no clean corridor for seed {seed}")


# ---------------------------------------------------------------------------------------
# intersections: blocks on a street grid.

def _intersections(rng, seed, n_blocks, block_size, street, altitude, ceiling,
                   start_clearance, start_free_ahead, pillar_radius, pillar_offset,
                   pillar_spacing):
    floor = make_appearance((0.16, 0.16, 0.18), (0.48, 0.48, 0.48), su=2.0, sv=0.5,
                            w_block=0.5, noise_scale=0.5, offset=rng.integers(0, 64, 2))
    ceil = make_appearance((0.50, 0.62, 0.82), (0.92, 0.94, 0.96), su=2.0, sv=2.0,
                           w_block=0.2, noise_scale=2.0, offset=rng.integers(0, 64, 2))

    def facade():                         # windows: tall cells, strong contrast
        c0 = hsv_to_rgb(rng.uniform(0.0, 1.0), rng.uniform(0.15, 0.5), rng.uniform(0.55, 0.9))
        c1 = hsv_to_rgb(rng.uniform(0.55, 0.65), rng.uniform(0.2, 0.5), rng.uniform(0.15, 0.35))
        su = rng.uniform(0.45, 0.7)
        return make_appearance(c0, c1, su=su, sv=su * rng.uniform(1.2, 1.8),
                               w_block=rng.uniform(0.65, 0.9), noise_scale=rng.uniform(0.8, 1.5),
                               offset=rng.integers(0, LATTICE_SIZE, 2))

    b = SceneBuilder(floor, ceil)
    nx, ny = _integers(rng, n_blocks), _integers(rng, n_blocks)

    def axis(count):
        widths = [_uniform(rng, street)]
        for _ in range(count):
            widths += [_uniform(rng, block_size), _uniform(rng, street)]
        return np.concatenate([[0.0], np.cumsum(widths)])

    xs, ys = axis(nx), axis(ny)
    arena = _rect(0, 0, xs[-1], ys[-1])
    _panel_walls(b, rng, arena, lambda: b.add_appearance(facade()), (4.0, 8.0))
    for i in range(nx):
        for j in range(ny):
            x0, x1, y0, y1 = xs[2 * i + 1], xs[2 * i + 2], ys[2 * j + 1], ys[2 * j + 2]
            if rng.random() < 0.5:            # one building, or two with a slit between
                b.add_polygon(_rect(x0, y0, x1, y1), b.add_appearance(facade()))
            elif rng.random() < 0.5:
                xm = rng.uniform(x0 + 1.5, x1 - 1.5)
                b.add_polygon(_rect(x0, y0, xm - 0.2, y1), b.add_appearance(facade()))
                b.add_polygon(_rect(xm + 0.2, y0, x1, y1), b.add_appearance(facade()))
            else:
                ym = rng.uniform(y0 + 1.5, y1 - 1.5)
                b.add_polygon(_rect(x0, y0, x1, ym - 0.2), b.add_appearance(facade()))
                b.add_polygon(_rect(x0, ym + 0.2, x1, y1), b.add_appearance(facade()))
    # Pillars along the centre line of every street (trees, lamp posts).
    streets = [np.array([[0.5 * (xs[2 * k] + xs[2 * k + 1]), 0.0],
                         [0.5 * (xs[2 * k] + xs[2 * k + 1]), ys[-1]]]) for k in range(nx + 1)]
    streets += [np.array([[0.0, 0.5 * (ys[2 * k] + ys[2 * k + 1])],
                          [xs[-1], 0.5 * (ys[2 * k] + ys[2 * k + 1])]]) for k in range(ny + 1)]
    crossings = np.array([[0.5 * (xs[2 * i] + xs[2 * i + 1]), 0.5 * (ys[2 * j] + ys[2 * j + 1])]
                          for i in range(nx + 1) for j in range(ny + 1)])
    for line in streets:
        for xy, radius, app in _pillars_along(rng, line, False, pillar_radius, pillar_offset,
                                              pillar_spacing, crossings, 3.5):
            b.add_circle(xy, radius, _round_circle(b, b.add_appearance(app), radius))
    return b.build("intersections", seed, altitude, ceiling, arena, (), start_clearance,
                   start_free_ahead)


_GENERATORS = {"basic": _basic, "channel": _channel, "intersections": _intersections,
               "corners": _corners}
