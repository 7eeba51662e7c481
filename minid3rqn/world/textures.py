"""Procedural, world-anchored surface appearance: colour as a function of a surface point.

Every surface point has 2D texture coordinates (s, h) in metres: on walls and prisms
s is the arc length along the obstacle's outline and h the height above the floor; on
the floor and the ceiling (s, h) = (x, y) in the world. The colour of a point is

    p(s, h)   = 1/2 + a_b w_b (B(s, h) - 1/2) + a_n w_n (N(s, h) - 1/2)      in [0, 1]
    colour    = gain * shade * (c0 + (c1 - c0) p)

- B: blocks. Cells of su x sv metres (rows offset by ``stagger`` cells, like bricks),
  each with a value drawn from a fixed random lattice.
- N: smooth value noise on a lattice of n metres (smoothstep-weighted bilinear
  interpolation, precomputed at 8 texels per cell in NOISE and read at the nearest texel).
- c0, c1: the appearance's two colours; w_b + w_n = 1 their pattern weights.
- shade: walls 0.6 + 0.4 (1 + n . l) / 2 with n the outward surface normal and l a fixed
  horizontal light direction (view-independent); 1 on the floor and the ceiling.
- a_b, a_n in [0, 1]: anti-aliasing. A pixel covers about f = Z / (fx cos theta)
  metres of surface (Z its depth, theta the angle between ray and normal; the renderer
  evaluates f once per column on walls and once per row on the floor and ceiling); a
  pattern of cell size L needs two or more pixels per cell, so its contrast is faded by
  a = clip((L / f - 1) / 2, 0, 1): full at three pixels per cell, gone at one. Far
  or grazing surfaces thus show their mean colour instead of aliasing noise, much as a
  real camera averages over the pixel's footprint.

So the colour depends on the surface point alone (up to that pre-filter), which keeps
views of the same point consistent, as photometric view synthesis needs.

The appearance table is a float32 array (A, N_PARAMS), one row per appearance; the
named column indices are below.
"""
from __future__ import annotations

import numpy as np

# Columns of an appearance row.
SU, SV, STAGGER, W_BLOCK, W_NOISE, NOISE_SCALE, OFF_X, OFF_Y, GAIN = range(9)
C0 = slice(9, 12)
C1 = slice(12, 15)
N_PARAMS = 15

LATTICE_BITS = 6
LATTICE_SIZE = 1 << LATTICE_BITS            # 64 x 64 values, tiles every 64 cells
LATTICE = np.random.default_rng(20200207).random((LATTICE_SIZE, LATTICE_SIZE)).astype(np.float32)
LIGHT = np.array([np.cos(0.7), np.sin(0.7)])  # fixed horizontal light direction (unit)

FLOOR_ID = 0        # appearance row of the floor in every scene
CEILING_ID = 1      # appearance row of the ceiling in every scene


def make_appearance(c0, c1, su=0.4, sv=0.4, stagger=0.0, w_block=0.6, noise_scale=0.8,
                    offset=(0, 0), gain=1.0) -> np.ndarray:
    """One appearance row (N_PARAMS,) float32.

    c0, c1: RGB in [0, 1]; su, sv: block size (m) along the surface and upwards; stagger:
    row offset in cells (0.5 = bricks); w_block: weight of blocks (noise gets 1 - w_block);
    noise_scale: value-noise cell (m); offset: integer lattice offsets that make two
    appearances with equal parameters look different; gain: overall brightness.
    """
    for name, value in (("su", su), ("sv", sv), ("noise_scale", noise_scale)):
        if not value > 0:
            raise ValueError(f"make_appearance: {name} must be > 0; got {value}")
    if not 0.0 <= w_block <= 1.0:
        raise ValueError(f"make_appearance: w_block must lie in [0, 1]; got {w_block}")
    if not 0.0 < gain <= 1.0:
        raise ValueError(f"make_appearance: gain must lie in (0, 1]; got {gain}")
    row = np.zeros(N_PARAMS, np.float32)
    row[[SU, SV, STAGGER, W_BLOCK, W_NOISE, NOISE_SCALE, OFF_X, OFF_Y, GAIN]] = (
        su, sv, stagger, w_block, 1.0 - w_block, noise_scale, offset[0], offset[1], gain)
    row[C0] = np.clip(c0, 0, 1)
    row[C1] = np.clip(c1, 0, 1)
    return row


def random_appearance(rng: np.random.Generator, hue_range=(0.0, 1.0), sat=(0.35, 0.75),
                      val=(0.45, 0.9), size=(0.25, 0.6), gain=1.0) -> np.ndarray:
    """A random appearance row: a base colour of hue in ``hue_range`` (fractions of the
    colour wheel), a contrasting accent, blocks of a size drawn from ``size`` (m) and a
    fine grain (value noise of 8-16 cm cells).

    Two scales, like real surfaces: the blocks give texture from afar, the grain up close
    (where a block covers pixels of flat colour that view synthesis cannot match)."""
    h = rng.uniform(*hue_range) % 1.0
    s, v = rng.uniform(*sat), rng.uniform(*val)
    c0 = hsv_to_rgb(h, s, v)
    # The accent is 35-65 % as bright as the base, so every surface carries visible
    # texture (brightness contrast >= 0.15): photometric view synthesis needs it, and so
    # do SSIM and the edge-aware smoothness, which are blind to faint patterns.
    c1 = hsv_to_rgb((h + rng.uniform(-0.08, 0.08)) % 1.0, s * rng.uniform(0.3, 0.9),
                    v * rng.uniform(0.35, 0.65))
    if rng.choice([False, True]):        # light pattern on dark, or dark on light
        c0, c1 = c1, c0
    su = rng.uniform(*size)
    kind = rng.integers(4)       # 0 blocks, 1 bricks, 2 vertical planks, 3 horizontal bands
    sv = {0: su, 1: su * 0.5, 2: 4.0, 3: su * 0.6}[int(kind)]
    su = {0: su, 1: su, 2: su * 0.6, 3: 4.0}[int(kind)]
    return make_appearance(c0, c1, su=su, sv=sv, stagger=0.5 if kind == 1 else 0.0,
                           w_block=rng.uniform(0.5, 0.7), noise_scale=rng.uniform(0.08, 0.16),
                           offset=rng.integers(0, LATTICE_SIZE, 2), gain=gain)


def hsv_to_rgb(h, s, v) -> np.ndarray:
    """HSV in [0, 1]^3 -> RGB in [0, 1]^3 (one colour)."""
    i = int(h * 6.0) % 6
    f = h * 6.0 - int(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    return np.array([(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i])


def _smooth_noise_image(factor: int = 8) -> np.ndarray:
    """LATTICE upsampled ``factor`` times with smoothstep-weighted bilinear interpolation,
    wrapping at the edges: (64 factor, 64 factor) float32 value noise."""
    t = np.arange(factor) / factor
    w = (t * t * (3 - 2 * t))[None, :, None]

    def upsample_rows(a):                  # row i f + k = (1 - w_k) a[i] + w_k a[i + 1]
        rows = (1 - w) * a[:, None, :] + w * np.roll(a, -1, axis=0)[:, None, :]
        return rows.reshape(-1, a.shape[1])

    return np.ascontiguousarray(upsample_rows(upsample_rows(LATTICE).T).T, dtype=np.float32)


NOISE_FACTOR = 8                       # noise texels per lattice cell
NOISE = _smooth_noise_image(NOISE_FACTOR)
NOISE_BITS = LATTICE_BITS + 3          # NOISE is 2**NOISE_BITS square
_LATTICE_FLAT, _NOISE_FLAT = LATTICE.reshape(-1), NOISE.reshape(-1)   # views, not copies

# Derived per-appearance constants, the form the renderer reads (see ``derived_table``).
(D_INV_SU, D_INV_SV, D_STAGGER, D_OX, D_OY, D_INV_NS, D_NOX, D_NOY, D_LB, D_LN) = range(10)
D_C0 = slice(10, 13)
D_DC = slice(13, 16)
D_WB, D_WN, D_GAIN = 16, 17, 18
N_DERIVED = 19


def derived_table(apps: np.ndarray) -> np.ndarray:
    """Appearance rows (..., N_PARAMS) -> renderer constants (..., N_DERIVED) float32:
    1/su, 1/sv, stagger, block offsets, NOISE texels per metre, noise offsets, the cell
    sizes L used by the anti-aliasing fade, the colours in 8-bit units with the gain
    applied, 255 gain c0 and 255 gain (c1 - c0), the pattern weights and the gain."""
    apps = np.asarray(apps, np.float32)
    d = np.zeros(apps.shape[:-1] + (N_DERIVED,), np.float32)
    with np.errstate(divide="ignore"):
        d[..., D_INV_SU] = 1.0 / apps[..., SU]
        d[..., D_INV_SV] = 1.0 / apps[..., SV]
        d[..., D_INV_NS] = NOISE_FACTOR / apps[..., NOISE_SCALE]
    d[..., D_STAGGER] = apps[..., STAGGER]
    d[..., D_OX], d[..., D_OY] = apps[..., OFF_X], apps[..., OFF_Y]
    # Noise offsets, plus 2^15 texels (a multiple of the NOISE size, so the same image)
    # to keep the coordinates of points within 2^15 / 8 cells of the origin positive.
    d[..., D_NOX] = (apps[..., OFF_Y] + 17) * NOISE_FACTOR + 2 ** 15
    d[..., D_NOY] = (apps[..., OFF_X] + 29) * NOISE_FACTOR + 2 ** 15
    d[..., D_LB] = np.minimum(apps[..., SU], apps[..., SV])
    d[..., D_LN] = apps[..., NOISE_SCALE]
    d[..., D_WB], d[..., D_WN] = apps[..., W_BLOCK], apps[..., W_NOISE]
    d[..., D_GAIN] = apps[..., GAIN]
    d[..., D_C0] = 255.0 * apps[..., GAIN, None] * apps[..., C0]
    d[..., D_DC] = 255.0 * apps[..., GAIN, None] * (apps[..., C1] - apps[..., C0])
    return d


# The lattice and the noise image minus 1/2 (the pattern reads B - 1/2 and N - 1/2); the
# float32 subtraction done once per texel gives the same values as doing it per pixel.
_LATTICE_CENTRED = _LATTICE_FLAT - np.float32(0.5)
_NOISE_CENTRED = _NOISE_FLAT - np.float32(0.5)
# Texel indices are int32 (half the memory traffic of int64): lattice coordinates stay far
# below 2^31 for any scene smaller than 10^7 m.
_TEXEL_MASKS = np.array([LATTICE_SIZE - 1, (1 << NOISE_BITS) - 1], np.int32).reshape(2, 1)
_ROW_SHIFTS = np.array([LATTICE_BITS, NOISE_BITS], np.int32).reshape(2, 1)


def pattern_from_coords(coords: np.ndarray, amp, stagger=None) -> np.ndarray:
    """The pattern value p in [0, 1] of surface points from their lattice coordinates.

    coords (2, 2, ...) float32, overwritten: [[s / su + o_x, h / sv + o_y],
    [s n + no_x, h n + no_y]] for texture coordinates (s, h), n the NOISE texels per
    metre (row 0 blocks, row 1 noise; column 0 along s, 1 along h; the constants are
    the ``derived_table`` columns). amp (2, ...): the faded pattern weights (a_b w_b,
    a_n w_n), a = clip((L / f - 1) / 2, 0, 1) for a pixel footprint of f metres (module
    docstring). stagger (...) or None when every stagger is 0.
    Block row j = floor(y_b), column i = floor(x_b + stagger (j mod 2)); the noise texel
    is (floor(x_n), floor(y_n)) (its coordinates are positive, so truncation floors). Then
        p = 1/2 + a_b w_b (LATTICE[j, i] - 1/2) + a_n w_n (NOISE[y_n, x_n] - 1/2),
    both images wrapping around (indices masked to their size).
    """
    blocks = coords[0]
    if stagger is None:
        np.floor(blocks, out=blocks)
        index = coords.astype(np.int32)                      # (2, 2, ...)
    else:
        x_b, y_b = blocks[0, ...], blocks[1, ...]            # views (0-d for one point)
        np.floor(y_b, out=y_b)                               # j = floor(y_b)
        index = coords.astype(np.int32)
        # j mod 2 is the low bit of j (also for negative j in two's complement); the
        # product stagger (j mod 2) is 0 or stagger, exact in float32 (the int 0 or 1 is
        # converted to float32 inside the multiply).
        x_b += np.multiply(stagger, index[0, 1, ...] & 1, dtype=np.float32)
        np.floor(x_b, out=x_b)
        index[0, 0, ...] = x_b                               # i = floor(x_b + stagger odd)
    index &= _TEXEL_MASKS.reshape((2, 1) + (1,) * (index.ndim - 2))
    index[:, 1] <<= _ROW_SHIFTS.reshape((2,) + (1,) * (index.ndim - 2))
    flat = index[:, 1] | index[:, 0]                         # row-major texel index
    p = _LATTICE_CENTRED.take(flat[0])
    p *= amp[0]                                               # a_b w_b (B - 1/2)
    p += 0.5
    noise = _NOISE_CENTRED.take(flat[1])
    noise *= amp[1]                                           # a_n w_n (N - 1/2)
    p += noise                                                # in place: fewer temporaries
    return p


def wall_shade(n_dot_l) -> np.ndarray:
    """Half-Lambert shade of vertical surfaces, 0.6 + 0.4 (1 + n . l) / 2, from the cosine
    n . l between the unit surface normal and the light direction ``LIGHT``."""
    return 0.6 + 0.2 * (1.0 + np.asarray(n_dot_l))
