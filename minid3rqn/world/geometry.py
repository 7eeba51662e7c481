"""Rigid motions between drone poses and the view-synthesis inverse warp, in NumPy.

World frame: x and y span the floor (metres), z points up; yaw is measured from the
world x axis, counter-clockwise seen from above. A drone pose is (x, y, yaw); its
camera sits at (x, y, altitude) and looks along (cos yaw, sin yaw, 0).

Camera frame (OpenCV, see ``camera.py``): x right, y down, z forward. Its axes written
in world coordinates are the columns of the rotation R_wc:

    right   = ( sin yaw, -cos yaw,  0)
    down    = (       0,        0, -1)          R_wc = [right | down | forward]
    forward = ( cos yaw,  sin yaw,  0)

and T_wc = [[R_wc, t], [0, 1]] with t = (x, y, altitude) maps camera coordinates to
world coordinates: P_w = R_wc P_c + t.

The relative transform between two poses a and b maps points in camera-a coordinates
to camera-b coordinates, T_{a->b} = T_wb^-1 T_wa. Both cameras fly at the same
altitude, so T_{a->b} does not depend on it.
"""
from __future__ import annotations

import numpy as np

PADDING_MODES = ("zeros", "border")
Z_EPS = 1e-3   # a point counts as in front of a camera iff its depth z > Z_EPS (metres)


def _as_poses(pose, name: str) -> np.ndarray:
    arr = np.asarray(pose, dtype=np.float64)
    if arr.ndim < 1 or arr.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3) holding (x, y, yaw); got shape "
                         f"{arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite; got {pose!r}")
    return arr


def rotation_world_from_camera(yaw) -> np.ndarray:
    """R_wc: (..., 3, 3) rotation whose columns are the camera's right, down, forward axes."""
    yaw = np.asarray(yaw, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    z = np.zeros_like(c)
    return np.stack([np.stack([s, z, c], -1),
                     np.stack([-c, z, s], -1),
                     np.stack([z, z - 1.0, z], -1)], -2)


def pose_to_camera_transform(pose, altitude: float = 1.0) -> np.ndarray:
    """T_wc, the world-from-camera transform of a pose: (..., 3) -> (..., 4, 4) float64.

    P_w = T_wc P_c in homogeneous coordinates, with the camera at (x, y, altitude).
    """
    poses = _as_poses(pose, "pose_to_camera_transform: pose")
    T = np.zeros(poses.shape[:-1] + (4, 4))
    T[..., :3, :3] = rotation_world_from_camera(poses[..., 2])
    T[..., 0, 3] = poses[..., 0]
    T[..., 1, 3] = poses[..., 1]
    T[..., 2, 3] = float(altitude)
    T[..., 3, 3] = 1.0
    return T


def invert_transform(T) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4): [[R^T, -R^T t], [0, 1]]."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape[-2:] != (4, 4):
        raise ValueError(f"invert_transform: T must have shape (..., 4, 4); got {T.shape}")
    R_t = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = R_t
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", R_t, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def relative_transform(pose_a, pose_b) -> np.ndarray:
    """T_{a->b} = T_wb^-1 T_wa: (..., 3), (..., 3) -> (..., 4, 4) float64.

    Maps a point in camera-a coordinates to camera-b coordinates: P_b = T_{a->b} P_a.
    For the view-synthesis warp of a source frame s into a target frame t, pass
    ``relative_transform(pose_t, pose_s)`` as ``T_tgt_to_src``.
    """
    a = _as_poses(pose_a, "relative_transform: pose_a")
    b = _as_poses(pose_b, "relative_transform: pose_b")
    return invert_transform(pose_to_camera_transform(b)) @ pose_to_camera_transform(a)


def backproject(depth, K) -> np.ndarray:
    """Camera-frame points of every pixel: P(u, v) = D(u, v) K^-1 [u, v, 1]^T.

    depth (..., H, W) -> points (..., H, W, 3) float64.
    """
    depth = np.asarray(depth, dtype=np.float64)
    K_inv = np.linalg.inv(np.asarray(K, dtype=np.float64))
    h, w = depth.shape[-2:]
    v, u = np.meshgrid(np.arange(h, dtype=np.float64), np.arange(w, dtype=np.float64),
                       indexing="ij")
    rays = np.stack([u, v, np.ones_like(u)], -1) @ K_inv.T         # (H, W, 3)
    return depth[..., None] * rays


def project(points, K) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates of camera-frame points: (u, v) = (K P)[:2] / max(z, Z_EPS).

    points (..., 3) -> (coords (..., 2) as (x = column, y = row), z (...)).
    """
    points = np.asarray(points, dtype=np.float64)
    p = points @ np.asarray(K, dtype=np.float64).T
    z = points[..., 2]
    return p[..., :2] / np.maximum(p[..., 2:3], Z_EPS), z


def bilinear_sample_numpy(image, coords, padding: str = "zeros") -> tuple[np.ndarray, np.ndarray]:
    """Sample a channel-last image at real pixel coordinates, bilinearly.

    image (N, H, W, C), coords (N, Ho, Wo, 2) as (x = column, y = row), pixel centres at
    integers -> (out (N, Ho, Wo, C) float64, valid (N, Ho, Wo) bool).

    With x0 = floor(x), wx = x - x0 (likewise y) and I_ab = image[y0 + a, x0 + b]:
        out = (1-wx)(1-wy) I00 + wx(1-wy) I01 + (1-wx) wy I10 + wx wy I11.
    valid = 0 <= x <= W-1 and 0 <= y <= H-1. padding "zeros": a corner outside the image
    reads 0 (torch ``grid_sample(..., padding_mode="zeros", align_corners=True)``);
    "border": x, y are first clamped to [0, W-1] x [0, H-1]. This is the forward pass
    of ``minid3rqn.autograd.sample.bilinear_sample`` in channel-last layout.
    """
    if padding not in PADDING_MODES:
        raise ValueError(f"bilinear_sample_numpy: padding must be one of {PADDING_MODES}; "
                         f"got {padding!r}")
    image = np.asarray(image, dtype=np.float64)
    coords = np.asarray(coords, dtype=np.float64)
    n, h, w, ch = image.shape
    x, y = coords[..., 0], coords[..., 1]
    valid = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    if padding == "border":
        x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    else:
        x, y = np.clip(x, -2, w + 1), np.clip(y, -2, h + 1)
    x0f, y0f = np.floor(x), np.floor(y)
    wx, wy = x - x0f, y - y0f
    x0, y0 = x0f.astype(np.int64), y0f.astype(np.int64)
    flat = image.reshape(n, h * w, ch)
    batch = np.arange(n).reshape((n,) + (1,) * (x.ndim - 1))
    out = np.zeros(x.shape + (ch,))
    for dy, wgt_y in ((0, 1.0 - wy), (1, wy)):
        for dx, wgt_x in ((0, 1.0 - wx), (1, wx)):
            xi, yi = x0 + dx, y0 + dy
            inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
            values = flat[batch, np.where(inside, yi * w + xi, 0)]
            out += (wgt_y * wgt_x * inside)[..., None] * values
    return out, valid


def inverse_warp_numpy(src_rgb, tgt_depth, K, T_tgt_to_src, padding: str = "zeros"):
    """Synthesize the target view by reading the source image where target pixels land.

    For every target pixel p_t = (u, v, 1) with depth D_t(p_t):

        P_t = D_t(p_t) K^-1 p_t                 (back-project, target camera frame)
        P_s = R P_t + t,  T_tgt_to_src = [[R, t], [0, 1]]        (into the source frame)
        p_s = (K P_s)[:2] / max(z_s, Z_EPS),    z_s = (P_s)_z    (project; Z_EPS = 1e-3)
        warped(p_t) = bilinear sample of src at p_s      (``bilinear_sample_numpy``)

    i.e. p_s ~ K T_{t->s} D_t(p_t) K^-1 p_t. A pixel is valid iff p_s lies in
    [0, W-1] x [0, H-1] (pixel centres at integers), z_s > Z_EPS and D_t(p_t) > 0.
    padding "zeros": corners outside the image read 0 and invalid pixels are set to 0;
    "border": coordinates are clamped into the image and every pixel keeps its sample.

    Args:
        src_rgb: source image, (H, W), (H, W, C) or batched (N, H, W, C); any real or
            uint8 dtype (read as float).
        tgt_depth: target depth (H, W) or (N, H, W), pinhole depth in metres.
        K: (3, 3) intrinsics.
        T_tgt_to_src: (4, 4) or (N, 4, 4), e.g. ``relative_transform(pose_t, pose_s)``.
        padding: "zeros" or "border".

    Returns:
        (warped, valid): warped has the shape of ``src_rgb`` (float32 for uint8/float32
        input, float64 for float64 input); valid is a bool array of the depth's shape.
    """
    if padding not in PADDING_MODES:
        raise ValueError(f"inverse_warp_numpy: padding must be one of {PADDING_MODES}; "
                         f"got {padding!r}")
    src = np.asarray(src_rgb)
    if src.dtype.kind not in "uif":
        raise TypeError(f"inverse_warp_numpy: src_rgb must be numeric; got dtype {src.dtype}")
    out_dtype = np.float64 if src.dtype == np.float64 else np.float32
    depth = np.asarray(tgt_depth, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    T = np.asarray(T_tgt_to_src, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"inverse_warp_numpy: K must have shape (3, 3); got {K.shape}")
    if depth.ndim not in (2, 3):
        raise ValueError(f"inverse_warp_numpy: tgt_depth must be (H, W) or (N, H, W); got "
                         f"shape {depth.shape}")
    batched = depth.ndim == 3
    shape_in = src.shape
    if batched:
        if src.ndim == 3:
            src = src[..., None]
        if src.ndim != 4 or src.shape[:3] != depth.shape:
            raise ValueError(f"inverse_warp_numpy: src_rgb must be (N, H, W[, C]) matching "
                             f"tgt_depth {depth.shape}; got shape {shape_in}")
        if T.shape == (4, 4):
            T = np.broadcast_to(T, (depth.shape[0], 4, 4))
    else:
        if src.ndim == 2:
            src = src[..., None]
        if src.ndim != 3 or src.shape[:2] != depth.shape:
            raise ValueError(f"inverse_warp_numpy: src_rgb must be (H, W[, C]) matching "
                             f"tgt_depth {depth.shape}; got shape {shape_in}")
        src, depth = src[None], depth[None]
        if T.shape == (4, 4):
            T = T[None]
    if T.shape != (depth.shape[0], 4, 4):
        raise ValueError(f"inverse_warp_numpy: T_tgt_to_src must be (4, 4) or (N, 4, 4) with "
                         f"N = {depth.shape[0]}; got shape {np.shape(T_tgt_to_src)}")
    points_t = backproject(depth, K)                                     # (N, H, W, 3)
    points_s = (np.einsum("nij,nhwj->nhwi", T[:, :3, :3], points_t)
                + T[:, None, None, :3, 3])
    coords, z_s = project(points_s, K)
    warped, valid = bilinear_sample_numpy(src, coords, padding)
    valid &= (z_s > Z_EPS) & (depth > 0)
    if padding == "zeros":
        warped *= valid[..., None]
    warped = warped.astype(out_dtype).reshape(shape_in)
    if not batched:
        valid = valid[0]
    return warped, valid
