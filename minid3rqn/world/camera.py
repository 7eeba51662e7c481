"""The pinhole camera: intrinsics K, pixel rays and the pixel-centre convention.

Frames. The camera frame follows OpenCV: x points right, y down, z forward (along the
optical axis). A point P = (X, Y, Z) in the camera frame lands on pixel

    u = fx X / Z + cx,        v = fy Y / Z + cy,        i.e.  Z [u, v, 1]^T = K P,

        | fx  0  cx |
    K = |  0 fy  cy |,         fx = fy = (W / 2) / tan(hfov / 2),
        |  0  0   1 |          cx = (W - 1) / 2,  cy = (H - 1) / 2 (by default).

The optical axis is horizontal (the drone flies level), so row cy is the horizon. By
default it is the middle row. ``horizon_row`` moves it up: the camera then sees more of
the floor below the horizon and less above it, as if the lower part of a taller image
were kept (a shifted lens, as in architectural cameras). Vertical edges stay vertical,
so every column is still one horizontal ray (the renderer relies on that).

Pixel centres sit at integer coordinates: pixel (u, v) (column u, row v) covers
[u - 1/2, u + 1/2] x [v - 1/2, v + 1/2], so the image spans [-1/2, W - 1/2] horizontally
and its centre is cx = (W - 1) / 2. The horizontal field of view ``hfov`` is the angle
between the outer edges of the first and last columns, which are W / 2 pixels from cx;
that fixes fx. The vertical field of view follows: vfov = 2 atan((H / 2) / fy).

Depth. The depth of a pixel is Z, the coordinate of the seen point along the optical
axis (pinhole depth), not the length of the ray. The ray through pixel (u, v) is
K^-1 [u, v, 1]^T = (x_n, y_n, 1) with x_n = (u - cx) / fx and y_n = (v - cy) / fy, and
the point it sees at depth Z is Z (x_n, y_n, 1).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class Camera:
    """A forward-looking pinhole camera with square pixels, its principal point centred
    horizontally.

    Args:
        height: image rows H (default 32: the paper's 128 scaled by 1/4).
        width: image columns W (default 104: the paper's 416 scaled by 1/4).
        hfov_deg: horizontal field of view in degrees, in (0, 180). Default 90: at
            32x104 this gives fx = fy = 52 px and a vertical field of view of 34.2 deg.
        horizon_row: the image row of the horizon, cy, in [0, H - 1]; None (default) puts
            it in the middle, (H - 1) / 2. Flying h = 1 m high, the lowest row (slope
            y_n = (H - 1 - cy) / fy) meets the floor h / y_n ahead, 3.35 m with the
            default camera: a wall nearer than that hides its foot (docs/depth.md
            section 7). ``horizon_row=4`` brings that to 1.93 m.
    """

    height: int = 32
    width: int = 104
    hfov_deg: float = 90.0
    horizon_row: float | None = None

    def __post_init__(self):
        for name in ("height", "width"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise TypeError(f"Camera: {name} must be an int; got {type(value).__name__}")
            if value < 1:
                raise ValueError(f"Camera: {name} must be >= 1; got {value}")
            object.__setattr__(self, name, int(value))
        fov = self.hfov_deg
        if isinstance(fov, bool) or not isinstance(fov, (int, float, np.integer, np.floating)):
            raise TypeError(f"Camera: hfov_deg must be a number; got {type(fov).__name__}")
        if not (0.0 < float(fov) < 180.0):
            raise ValueError(f"Camera: hfov_deg must lie in (0, 180) degrees; got {fov}")
        object.__setattr__(self, "hfov_deg", float(fov))
        row = self.horizon_row
        if row is not None:
            if isinstance(row, bool) or not isinstance(row, (int, float, np.integer,
                                                              np.floating)):
                raise TypeError(f"Camera: horizon_row must be a number or None; got "
                                f"{type(row).__name__}")
            if not (0.0 <= float(row) <= self.height - 1):
                raise ValueError(f"Camera: horizon_row must lie in [0, H - 1] = [0, "
                                 f"{self.height - 1}] (a row of the image); got {row}")
            row = float(row)
            if row == (self.height - 1) / 2.0:
                row = None                       # the default camera, one way of writing it
            object.__setattr__(self, "horizon_row", row)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W)."""
        return (self.height, self.width)

    @property
    def fx(self) -> float:
        """Focal length in pixels, (W / 2) / tan(hfov / 2); fy = fx."""
        return 0.5 * self.width / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def fy(self) -> float:
        return self.fx

    @property
    def cx(self) -> float:
        return (self.width - 1) / 2.0

    @property
    def cy(self) -> float:
        """The horizon row: ``horizon_row``, or the middle row (H - 1) / 2."""
        return (self.height - 1) / 2.0 if self.horizon_row is None else self.horizon_row

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx],
                         [0.0, self.fy, self.cy],
                         [0.0, 0.0, 1.0]])

    def column_rays(self) -> np.ndarray:
        """(W,) float64 x_n = (u - cx) / fx: the ray slope of each column (read-only)."""
        return self._rays[0]

    def row_rays(self) -> np.ndarray:
        """(H,) float64 y_n = (v - cy) / fy: the ray slope of each row, positive down
        (read-only)."""
        return self._rays[1]

    @cached_property
    def _rays(self):
        xn = (np.arange(self.width) - self.cx) / self.fx
        yn = (np.arange(self.height) - self.cy) / self.fy
        xn.setflags(write=False)
        yn.setflags(write=False)
        return xn, yn
