"""The self-supervised depth loss: photometric view synthesis plus disparity smoothness.

For a target frame I_t, its sources I_s (s = previous, next), the predicted disparity
at scales i = 0..n-1 and the predicted poses T_{t->s}:

    D_t^i       = 1 / disp_i, I^i = I downsampled 2^i x (area mean), K^i = K scaled
                  (SfMLearner; ``full_res``: D_t^i = 1 / upsample(disp_i) and full-size
                  images, as monodepth2)
    I_s->t^i    = inverse_warp(I_s^i, D_t^i, T_{t->s}, K^i)    geometry.inverse_warp
    pe(a, b)    = alpha (1 - SSIM(a, b)) / 2 + (1 - alpha) |a - b|,  mean over RGB
                                                               photometric_error
    e^i(p)      = min_s pe(I_s->t^i, I_t)(p)      per-pixel minimum over the sources,
                  over the sources whose warp lands inside the image (min_reprojection;
                  else the mean of pe over all pixels and sources, as SfMLearner)
    L_photo     = (1/n) sum_i mean_p min(e^i(p), min_s pe(I_s^i, I_t^i)(p))
                  (auto-masking as in monodepth2: a pixel that the *unwarped* sources
                  explain better costs that constant error and sends no gradient;
                  without it L_photo = mean_{i,p} e^i(p))
    L_smooth    = (1/n) sum_i 2^-i mean_p (|dx d*| e^{-|dx I|} + |dy d*| e^{-|dy I|})
                  d* = disp_i / mean(disp_i) (mean-normalised, so shrinking the
                  disparity cannot cheat), I the target at scale i; edge-aware weights
                  e^{-|grad I|} are 1 when ``edge_aware`` is False   smoothness_loss
    L_speed     = mean_{n,s} | |t_{t->s}| - k_s v dt |  (k_s frames between t and s;
                  optional, weight mu: the drone's
                  known speed, 2 m/s x 0.4 s = 0.8 m between frames, as PackNet-SfM's
                  velocity supervision; it fixes the scale to metres and speeds up
                  the pose; it reads no ground truth)
    L           = L_photo + lambda L_smooth + mu L_speed        view_synthesis_loss
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .. import autograd as ag
from ..autograd import Tensor
from .geometry import crop, inverse_warp, pose_vec_to_mat, scale_intrinsics

from ..autograd.conv import upsample

SSIM_C1, SSIM_C2 = 0.01 ** 2, 0.03 ** 2
INVALID = 1.0e3      # added to the error of out-of-view pixels so the minimum skips them


@dataclass
class LossConfig:
    ssim_weight: float = 0.85       # alpha; 0 gives SfMLearner's plain L1
    smooth_weight: float = 1e-3     # lambda (monodepth2: 1e-3)
    edge_aware: bool = True
    smooth_order: int = 1           # 1: |grad d| (monodepth2); 2: |grad^2 d| (planes are free)
    min_reprojection: bool = True   # per-pixel min over sources (monodepth2)
    automask: bool = True           # monodepth2's auto-masking
    padding: str = "border"         # sampler padding for the warp
    full_res: bool = False          # True: monodepth2 (upsample disp); False: SfMLearner
                                    # (downsample images: a wider basin at coarse scales)
    unmasked_weight: float = 0.0    # beta: + beta mean(e) keeps a gradient on masked pixels
    speed_weight: float = 0.1       # mu; 0 disables the known-speed term
    gyro_weight: float = 0.0        # nu; > 0 adds the gyro term (needs ``gyro`` yaws)
    step: float = 0.8               # metres flown between frames (2 m/s x 0.4 s)

    def to_dict(self) -> dict:
        return asdict(self)


# -- SSIM ------------------------------------------------------------------------------
def box3(x) -> Tensor:
    """3x3 mean filter over H, W with edge padding; separable: rows then columns."""
    x = ag.pad(x, ((0, 0), (0, 0), (1, 1), (1, 1)), mode="edge")
    h, w = x.shape[2] - 2, x.shape[3] - 2
    all_ = slice(None)
    rows = (crop(x, (all_, all_, slice(0, h))) + crop(x, (all_, all_, slice(1, h + 1)))
            + crop(x, (all_, all_, slice(2, h + 2))))
    cols = (crop(rows, (all_, all_, all_, slice(0, w)))
            + crop(rows, (all_, all_, all_, slice(1, w + 1)))
            + crop(rows, (all_, all_, all_, slice(2, w + 2))))
    return cols * (1.0 / 9.0)


def ssim_dissimilarity(x, y) -> Tensor:
    """(1 - SSIM(x, y)) / 2 per pixel and channel, clipped to [0, 1]; 3x3 windows.

    SSIM = (2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_x^2 + s_y^2 + C2)).
    """
    x, y = ag.as_tensor(x), ag.as_tensor(y)
    mu_x, mu_y = box3(x), box3(y)
    s_x = box3(x * x) - mu_x * mu_x
    s_y = box3(y * y) - mu_y * mu_y
    s_xy = box3(x * y) - mu_x * mu_y
    num = (2.0 * mu_x * mu_y + SSIM_C1) * (2.0 * s_xy + SSIM_C2)
    den = (mu_x * mu_x + mu_y * mu_y + SSIM_C1) * (s_x + s_y + SSIM_C2)
    return ag.clip((1.0 - num / den) * 0.5, 0.0, 1.0)


def photometric_error(pred, target, ssim_weight: float = 0.85) -> Tensor:
    """pe = alpha (1 - SSIM)/2 + (1 - alpha) |pred - target|, mean over channels.

    pred, target (N, C, H, W) -> (N, 1, H, W).
    """
    pred, target = ag.as_tensor(pred), ag.as_tensor(target)
    err = ag.mean(ag.abs(pred - target), axis=1, keepdims=True)
    if ssim_weight > 0:
        ssim = ag.mean(ssim_dissimilarity(pred, target), axis=1, keepdims=True)
        err = ssim * ssim_weight + err * (1.0 - ssim_weight)
    return err


# -- smoothness ------------------------------------------------------------------------
def downsample_image(image: np.ndarray, factor: int) -> np.ndarray:
    """Area-average (N, C, H, W) by ``factor`` (H, W divisible by it); NumPy, no grad."""
    if factor == 1:
        return image
    n, c, h, w = image.shape
    if h % factor or w % factor:
        raise ValueError(f"downsample_image: {h}x{w} is not divisible by {factor}")
    return image.reshape(n, c, h // factor, factor, w // factor, factor).mean(axis=(3, 5))


def smoothness_loss(disp, image, edge_aware: bool = True, order: int = 1) -> Tensor:
    """mean |dx^k d*| w_x + mean |dy^k d*| w_y with d* = disp / mean(disp) per image.

    disp (N, 1, h, w) Tensor, image (N, C, h, w) array. ``order`` k = 1 penalises slopes
    (monodepth2), so a plane seen at an angle pays for its depth gradient; k = 2 uses
    the second difference d[u+1] - 2 d[u] + d[u-1], which is zero on every plane (1/Z of
    a plane is an affine function of the pixel: walls, floor and ceiling cost nothing).
    w = exp(-mean_c |grad I|) when ``edge_aware`` (disparity may bend where the image has
    an edge; for k = 2 the product of the two neighbouring weights), else 1.
    """
    if order not in (1, 2):
        raise ValueError(f"smoothness_loss: order must be 1 or 2; got {order}")
    disp = ag.as_tensor(disp)
    a = slice(None)
    d = disp * (1.0 / (ag.mean(disp, axis=(2, 3), keepdims=True) + 1e-7))

    def diff(x, axis):                       # first difference along axis 2 or 3
        hi = [a, a, a, a]
        lo = [a, a, a, a]
        hi[axis], lo[axis] = slice(1, None), slice(0, -1)
        return crop(x, tuple(hi)) - crop(x, tuple(lo))

    dx, dy = diff(d, 3), diff(d, 2)
    if order == 2:
        dx, dy = diff(dx, 3), diff(dy, 2)
    dx, dy = ag.abs(dx), ag.abs(dy)
    if edge_aware:
        image = np.asarray(image, dtype=disp.dtype)
        wx = np.exp(-np.abs(np.diff(image, axis=3)).mean(axis=1, keepdims=True))
        wy = np.exp(-np.abs(np.diff(image, axis=2)).mean(axis=1, keepdims=True))
        if order == 2:
            wx, wy = wx[..., 1:] * wx[..., :-1], wy[..., 1:, :] * wy[..., :-1, :]
        dx, dy = dx * wx, dy * wy
    return ag.mean(dx) + ag.mean(dy)


# -- the whole loss --------------------------------------------------------------------
def _photometric_term(target, sources, depth, T, K, cfg):
    """L_photo at one scale: target (N, 3, h, w), sources S x (N, 3, h, w), depth
    (N, 1, h, w) Tensor, T (S N, 4, 4) Tensor in (s, n) order. Returns (Tensor, mask)."""
    n, _, h, w = target.shape
    s_count = len(sources)
    dtype = target.dtype
    depth_all = ag.concat([depth] * s_count, axis=0) if s_count > 1 else depth
    warped, valid = inverse_warp(np.concatenate(sources, axis=0), depth_all, T, K,
                                 cfg.padding)
    err = photometric_error(warped, np.concatenate([target] * s_count, axis=0),
                            cfg.ssim_weight)                          # (S N, 1, h, w)
    err = ag.reshape(err, (s_count, n, 1, h, w))
    valid = valid.reshape(s_count, n, 1, h, w)
    if not cfg.min_reprojection:
        # SfMLearner: the mean error over every pixel and source. Out-of-view pixels
        # read 0 with "zeros" padding and so cost a large error: averaging over the
        # valid pixels only would let a pose that pushes everything out of view win.
        return ag.mean(err), valid
    # A source whose warp leaves the image is skipped by the minimum (+INVALID).
    masked = err + INVALID * (1.0 - valid) if cfg.automask else err
    best = crop(masked, (0,))
    for s in range(1, s_count):
        best = ag.minimum(best, crop(masked, (s,)))                      # (N, 1, h, w)
    if not cfg.automask:
        return ag.mean(best), np.ones(best.shape, dtype)
    # monodepth2's auto-mask as a minimum: a pixel costs the smaller of the best
    # reprojection error and the best identity (unwarped) error, so the gradient flows
    # only where the warp explains the pixel better than no motion, and no prediction
    # can lower the loss by pushing pixels out of view.
    identity = photometric_error(np.concatenate(sources, axis=0),
                                 np.concatenate([target] * s_count, axis=0),
                                 cfg.ssim_weight).data.reshape(s_count, n, 1, h, w)
    identity = identity.min(axis=0).astype(dtype)
    photo = ag.mean(ag.minimum(best, identity))
    if cfg.unmasked_weight > 0:
        # A weak unmasked term: where every warp is worse than no warp (a wrong-sign yaw,
        # a depth far too near) the auto-mask alone sends no gradient at all.
        photo = photo + ag.mean(ag.minimum(best, 1.0)) * cfg.unmasked_weight
    return photo, (best.data < identity).astype(dtype)



def view_synthesis_loss(target, sources, disps, poses, K, config: LossConfig | None = None,
                        gyro=None, source_steps=None):
    """L = L_photo + lambda L_smooth (module docstring) for one batch.

    Args:
        target: (N, 3, H, W) float array in [0, 1].
        sources: list of S arrays (N, 3, H, W), the neighbours of the target.
        disps: list of disparity Tensors, scale i of shape (N, 1, H / 2^i, W / 2^i).
        poses: (N, S, 6) Tensor of pose vectors T_{t->s}.
        K: (3, 3) intrinsics of the (H, W) images.
        gyro: (N, S) yaw (rotation about the camera's vertical axis, ry) of T_{t->s} as
            the drone's rate gyro measures it; used when ``config.gyro_weight`` > 0.
        source_steps: (S,) frames between the target and each source (default all 1):
            the known-speed term expects ``config.step`` times that.

    Returns:
        (loss, info): a scalar Tensor and a dict of floats (photo, smooth, mask).
    """
    cfg = config or LossConfig()
    target = np.asarray(target.data if isinstance(target, Tensor) else target)
    dtype = target.dtype
    n, _, h, w = target.shape
    s_count = len(sources)
    if s_count < 1:
        raise ValueError("view_synthesis_loss: needs at least one source frame")
    sources = [np.asarray(s.data if isinstance(s, Tensor) else s, dtype=dtype) for s in sources]
    for i, src in enumerate(sources):
        if src.shape != target.shape:
            raise ValueError(f"view_synthesis_loss: sources[{i}] has shape {src.shape}; the "
                             f"target has {target.shape}")
    poses = ag.as_tensor(poses)
    if poses.shape != (n, s_count, 6):
        raise ValueError(f"view_synthesis_loss: poses must be (N, S, 6) = {(n, s_count, 6)}; "
                         f"got {poses.shape}")
    n_sc = len(disps)

    # Pose matrices for every (source, image): batch order (s, n).
    T = pose_vec_to_mat(ag.reshape(ag.transpose(poses, (1, 0, 2)), (s_count * n, 6)))
    photos, masks = [], []
    for i, disp in enumerate(disps):
        factor = 2 ** i
        if disp.shape != (n, 1, -(-h // factor), -(-w // factor)):
            raise ValueError(f"view_synthesis_loss: disps[{i}] must be (N, 1, H/{factor}, "
                             f"W/{factor}) = {(n, 1, h // factor, w // factor)}; got {disp.shape}")
        if cfg.full_res:          # monodepth2: upsample the disparity, warp full images
            depth = 1.0 / (disp if factor == 1 else upsample(disp, factor, "bilinear"))
            tgt_i, srcs_i, K_i = target, sources, K
        else:                     # SfMLearner: warp images downsampled to the scale
            depth = 1.0 / disp
            tgt_i = downsample_image(target, factor)
            srcs_i = [downsample_image(src, factor) for src in sources]
            K_i = scale_intrinsics(K, 1.0 / factor)
        photo_i, mask_i = _photometric_term(tgt_i, srcs_i, depth, T, K_i, cfg)
        photos.append(photo_i)
        masks.append(mask_i)
    photo = photos[0]
    for term in photos[1:]:
        photo = photo + term
    photo = photo * (1.0 / n_sc)
    mask = np.concatenate([m.ravel() for m in masks])

    smooth = None
    for i, disp in enumerate(disps):
        term = smoothness_loss(disp, downsample_image(target, 2 ** i), cfg.edge_aware,
                               cfg.smooth_order)
        term = term * (1.0 / 2 ** i)
        smooth = term if smooth is None else smooth + term
    smooth = smooth * (1.0 / n_sc)
    loss = photo + smooth * cfg.smooth_weight
    info = {"photo": float(photo.data), "smooth": float(smooth.data),
            "mask": float(mask.mean())}
    if cfg.speed_weight > 0:
        t = crop(poses, (slice(None), slice(None), slice(0, 3)))
        norm = ag.sqrt(ag.sum(t * t, axis=2) + 1e-12)
        if source_steps is None:
            expected = cfg.step
        else:
            expected = cfg.step * np.asarray(source_steps, dtype=poses.dtype)
            if expected.shape != (s_count,):
                raise ValueError(f"view_synthesis_loss: source_steps needs one entry per "
                                 f"source ({s_count}); got shape {expected.shape}")
        speed = ag.mean(ag.abs(norm - expected))
        loss = loss + speed * cfg.speed_weight
        info["speed"] = float(speed.data)
    if cfg.gyro_weight > 0:
        # The gyro term: L_gyro = mean |ry - ry_gyro|. A drone's rate gyro measures its
        # yaw between frames; pulling PoseNet's yaw toward it is visual-inertial
        # learning (it reads no depth). Without it PoseNet may never find the yaw's sign
        # in the open basic world (docs/depth.md).
        if gyro is None or np.shape(gyro) != (n, s_count):
            raise ValueError(f"view_synthesis_loss: gyro_weight > 0 needs gyro yaws of shape "
                             f"(N, S) = {(n, s_count)}; got "
                             f"{None if gyro is None else np.shape(gyro)}")
        ry = crop(poses, (slice(None), slice(None), 4))
        gyro_term = ag.mean(ag.abs(ry - np.asarray(gyro, dtype=poses.dtype)))
        loss = loss + gyro_term * cfg.gyro_weight
        info["gyro"] = float(gyro_term.data)
    return loss, info


__all__ = ["LossConfig", "box3", "ssim_dissimilarity", "photometric_error",
           "downsample_image", "smoothness_loss", "view_synthesis_loss"]
