"""View-synthesis geometry on autograd Tensors: pose vectors, back-projection, the warp.

The equation every function here serves (the paper's Eq. 3; SfMLearner, Zhou et al.
2017, Eq. 2):

    p_s ~ K T_{t->s} D_t(p_t) K^-1 p_t

read right to left, one function per step:

    1. rays     r(p_t) = K^-1 [u, v, 1]^T                      ``pixel_rays``
    2. points   P_t = D_t(p_t) r(p_t)    (target camera frame)  ``inverse_warp``
    3. motion   P_s = R P_t + t,  T_{t->s} = [[R, t], [0, 1]]   ``pose_vec_to_mat``
    4. project  p_s = (K P_s)[:2] / max(z_s, Z_EPS)             ``inverse_warp``
    5. sample   I_s->t(p_t) = bilinear(I_s, p_s)                ``ag.bilinear_sample``

Steps 3 and 4 are folded into one batched product: K P_s = (K R) P_t + K t.
Conventions follow ``minid3rqn.world``: OpenCV camera frame (x right, y down,
z forward), pixel centres at integer coordinates, K with cx = (W-1)/2, cy = (H-1)/2.
``inverse_warp`` gives the same numbers as ``world.geometry.inverse_warp_numpy``
(tested), but every step is differentiable with respect to depth, pose and image.
"""
from __future__ import annotations

import numpy as np

from .. import autograd as ag
from ..autograd import Tensor
from ..autograd.engine import as_tensor
from ..autograd.sample import bilinear_sample
from ..autograd.shape import crop

Z_EPS = 1e-3     # the world's convention: a point is in front of a camera iff z > Z_EPS


# -- two small ops the autograd package does not have -------------------------------
def sin(x) -> Tensor:
    """y = sin x;  dy/dx = cos x."""
    x = as_tensor(x)
    return Tensor.from_op(np.sin(x.data), (x,), lambda g: (g * np.cos(x.data),), "sin")


def cos(x) -> Tensor:
    """y = cos x;  dy/dx = -sin x."""
    x = as_tensor(x)
    return Tensor.from_op(np.cos(x.data), (x,), lambda g: (-g * np.sin(x.data),), "cos")


# -- pose ------------------------------------------------------------------------------
def euler_to_matrix(angles) -> Tensor:
    """Rotation matrices from Euler angles (N, 3) = (rx, ry, rz) -> (N, 3, 3).

    R = R_z(rz) R_y(ry) R_x(rx) (SfMLearner's ``euler2mat`` order), with
    R_x = [[1,0,0],[0,c,-s],[0,s,c]], R_y = [[c,0,s],[0,1,0],[-s,0,c]],
    R_z = [[c,-s,0],[s,c,0],[0,0,1]]. Differentiable in the angles.
    """
    angles = as_tensor(angles)
    if angles.ndim != 2 or angles.shape[1] != 3:
        raise ValueError(f"euler_to_matrix: angles must have shape (N, 3); got {angles.shape}")
    cx, sx = cos(angles[:, 0]), sin(angles[:, 0])
    cy, sy = cos(angles[:, 1]), sin(angles[:, 1])
    cz, sz = cos(angles[:, 2]), sin(angles[:, 2])
    # Written out: R = R_z R_y R_x, entry by entry.
    rows = [
        [cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
        [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
        [-sy, cy * sx, cy * cx],
    ]
    return ag.stack([ag.stack(r, axis=1) for r in rows], axis=1)


def pose_vec_to_mat(vec) -> Tensor:
    """6-DoF pose vectors (N, 6) = (tx, ty, tz, rx, ry, rz) -> transforms (N, 4, 4).

    T = [[R(rx, ry, rz), t], [0, 0, 0, 1]] with R from ``euler_to_matrix``; it maps
    target-camera points to source-camera points, P_s = R P_t + t (metres, radians,
    camera frame: x right, y down, z forward).
    """
    vec = as_tensor(vec)
    if vec.ndim != 2 or vec.shape[1] != 6:
        raise ValueError(f"pose_vec_to_mat: vec must have shape (N, 6) holding (tx, ty, tz, "
                         f"rx, ry, rz); got {vec.shape}")
    n = vec.shape[0]
    R = euler_to_matrix(vec[:, 3:6])
    t = ag.reshape(vec[:, 0:3], (n, 3, 1))
    top = ag.concat([R, t], axis=2)                                       # (N, 3, 4)
    bottom = np.zeros((n, 1, 4), dtype=vec.dtype)
    bottom[:, 0, 3] = 1.0
    return ag.concat([top, Tensor(bottom)], axis=1)


def matrix_to_pose_vec(T) -> np.ndarray:
    """The inverse of ``pose_vec_to_mat`` (NumPy, no gradient): (N, 4, 4) -> (N, 6).

    With R = R_z R_y R_x: ry = -asin(R20), rx = atan2(R21, R22), rz = atan2(R10, R00).
    """
    T = np.asarray(T, dtype=np.float64)
    R = T[..., :3, :3]
    ry = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    rx = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    rz = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.concatenate([T[..., :3, 3], np.stack([rx, ry, rz], -1)], axis=-1)


# -- intrinsics and rays ---------------------------------------------------------------
def check_intrinsics(K, height: int, width: int, name: str = "K") -> np.ndarray:
    """Validate K (3, 3) against an image of (height, width); return it as float64.

    The world's cameras put the principal point at the middle column, cx = (W-1)/2, and
    the horizon row cy inside the image (the middle row (H-1)/2 unless the camera's
    ``horizon_row`` moves it). K made for another image size (a common mistake when
    images are resized) breaks that, and the warp would silently read the wrong pixels.
    """
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"{name} must have shape (3, 3); got {K.shape}")
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"{name} must be finite with positive focal lengths; got {K.tolist()}")
    cx = (width - 1) / 2.0
    if abs(K[0, 2] - cx) > 0.5 or not (-0.5 <= K[1, 2] <= height - 0.5):
        raise ValueError(
            f"{name} does not match the image size {height}x{width}: its principal point is "
            f"(cx, cy) = ({K[0, 2]:g}, {K[1, 2]:g}) but an image of that size has its middle "
            f"column at cx = {cx:g} and its rows in [0, {height - 1}]. Scale K with the image "
            f"(see scale_intrinsics).")
    return K


def scale_intrinsics(K, factor: float) -> np.ndarray:
    """K for an image resized by ``factor`` (pixel centres at integers):
    f -> f * factor, c -> (c + 1/2) * factor - 1/2."""
    K = np.asarray(K, dtype=np.float64).copy()
    K[0, 0] *= factor
    K[1, 1] *= factor
    K[0, 2] = (K[0, 2] + 0.5) * factor - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * factor - 0.5
    return K


def pixel_rays(K, height: int, width: int, dtype=np.float32) -> np.ndarray:
    """r(p) = K^-1 [u, v, 1]^T for every pixel, as a (3, H*W) array (row-major pixels)."""
    v, u = np.meshgrid(np.arange(height, dtype=np.float64),
                       np.arange(width, dtype=np.float64), indexing="ij")
    pix = np.stack([u.ravel(), v.ravel(), np.ones(height * width)])      # (3, HW)
    return (np.linalg.inv(np.asarray(K, dtype=np.float64)) @ pix).astype(dtype)


# -- the warp --------------------------------------------------------------------------
def inverse_warp(src, depth, T_tgt_to_src, K, padding: str = "zeros"):
    """Synthesize the target view from a source image, the target depth and the motion.

    Args:
        src: source images, (N, C, H, W) Tensor or array.
        depth: target depth D_t, (N, 1, H, W) or (N, H, W), Tensor or array, > 0.
        T_tgt_to_src: (N, 4, 4) Tensor or array (``pose_vec_to_mat`` output, or
            ``world.geometry.relative_transform(pose_t, pose_s)``).
        K: (3, 3) intrinsics of images of this size (checked).
        padding: "zeros" (outside reads 0 and invalid pixels are zeroed, as the world's
            warp) or "border" (clamped coordinates, every pixel keeps its sample).

    Returns:
        (warped, valid): warped (N, C, H, W) Tensor, differentiable in src, depth and
        T; valid (N, 1, H, W) float array (1 where p_s falls inside the source image,
        z_s > Z_EPS and D_t > 0).
    """
    src = as_tensor(src)
    depth = as_tensor(depth, like=src)
    T = as_tensor(T_tgt_to_src, like=src)
    if src.ndim != 4:
        raise ValueError(f"inverse_warp: src must be (N, C, H, W); got shape {src.shape}")
    n, _, h, w = src.shape
    if depth.ndim == 3:
        depth = ag.reshape(depth, (depth.shape[0], 1) + depth.shape[1:])
    if depth.shape != (n, 1, h, w):
        raise ValueError(f"inverse_warp: depth must be (N, 1, H, W) = {(n, 1, h, w)} to match "
                         f"src {src.shape}; got {depth.shape}")
    if T.shape != (n, 4, 4):
        raise ValueError(f"inverse_warp: T_tgt_to_src must be (N, 4, 4) with N = {n}; got "
                         f"{T.shape}")
    K = check_intrinsics(K, h, w)
    dtype = src.dtype
    rays = pixel_rays(K, h, w, dtype)                                     # (3, HW)
    Kd = K.astype(dtype)
    points = ag.reshape(depth, (n, 1, h * w)) * rays                      # P_t (N, 3, HW)
    KR = ag.matmul(Kd, T[:, :3, :3])                                      # (N, 3, 3)
    Kt = ag.matmul(Kd, T[:, :3, 3:4])                                     # (N, 3, 1)
    proj = ag.matmul(KR, points) + Kt                                     # K P_s (N, 3, HW)
    z = crop(proj, (slice(None), 2))
    z_safe = ag.clip(z, low=Z_EPS)
    x = crop(proj, (slice(None), 0)) / z_safe
    y = crop(proj, (slice(None), 1)) / z_safe
    coords = ag.reshape(ag.stack([x, y], axis=-1), (n, h, w, 2))
    warped, valid = bilinear_sample(src, coords, padding)
    valid = valid * ((z.data > Z_EPS) & (depth.data.reshape(n, h * w) > 0)
                     ).reshape(n, 1, h, w).astype(dtype)
    if padding == "zeros":
        warped = warped * valid
    return warped, valid
