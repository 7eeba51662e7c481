"""The view-synthesis loss that trains DispNet and PoseNet without depth labels.

The paper's loss (Eq. 2, after SfMLearner, Zhou et al. 2017):

    L_vs = sum_s sum_p | I_t(p) - Î_s(p) |

I_t is the target frame, s runs over its neighbours I_{t-1} and I_{t+1}, p over the
pixels, and Î_s is the target view synthesized from source s. Each target pixel p_t
is carried into the source with the predicted depth D_t and motion T_{t->s} (Eq. 3)

    p_s ~ K T_{t->s} D_t(p_t) K^-1 p_t

and Î_s(p_t) = I_s(p_s), read bilinearly (``depth.geometry.inverse_warp``). The first
two functions below are these equations: ``reconstruction_errors`` gives the error of
every source and pixel, and with ``l1_error`` their sum is L_vs.

What we train with adds, to that one equation, pieces from later work (each marked
[name] where it is implemented):

    [SSIM]       pe(a, b) = alpha (1 - SSIM(a, b)) / 2 + (1 - alpha) |a - b|, mean over
                 RGB, alpha = 0.85 (monodepth2, Godard et al. 2019): a structural term
                 that is less fooled by brightness. alpha = 0 is the paper's L1.
    [min]        e(p) = min_s pe(I_t(p), Î_s(p)): the per-pixel minimum over the sources
                 instead of their sum, skipping a source whose warp leaves the image: a
                 pixel hidden in one neighbour is seen in the other (monodepth2).
    [auto-mask]  each pixel costs min(e(p), min_s pe(I_t(p), I_s(p))): where an
                 unwarped source explains the pixel better (no motion, a surface as far
                 as the sky), the pixel costs that constant and sends no gradient
                 (monodepth2's auto-masking, written as a minimum).
    [unmasked]   + beta mean_p min(e(p), 1): a weak term without the mask, so that a
                 batch the mask shuts entirely (a wrong-sign yaw, a depth far too near)
                 still gets a gradient (ours; ``unmasked_weight``).
    [scales]     L_photo = (1/n) sum_i of that term at each of the n = 4 scales i of
                 the disparity. SfMLearner warps images downsampled 2^i times with the
                 disparity of scale i; monodepth2 (our ``full_res``) upsamples each
                 disparity and warps the full images.
    [smooth]     lambda L_smooth, L_smooth = (1/n) sum_i 2^-i mean_p (|dx d*| e^{-|dx I|}
                 + |dy d*| e^{-|dy I|}), d* = disp_i / mean(disp_i): edge-aware
                 smoothness of the mean-normalised disparity (SfMLearner's smoothness
                 term, monodepth2's form), lambda = 1e-3.
    [speed]      mu mean_s | |t_{t->s}| - v dt |: the drone's known speed, 2 m/s x 0.4 s
                 = 0.8 m between frames, as PackNet-SfM's velocity supervision; it fixes
                 the scale to metres and reads no ground truth (ours), mu = 0.1.

    L = L_photo + lambda L_smooth + mu L_speed                  ``view_synthesis_loss``
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import autograd as ag
from ..autograd import Tensor
from ..autograd.conv import upsample
from ..autograd.shape import crop
from ..config import at_least, between, setting, validate
from .data import FRAME_DT, SPEED
from .geometry import inverse_warp, pose_vec_to_mat, scale_intrinsics


# -- the paper: Eq. 2 and Eq. 3 -----------------------------------------------------------
def l1_error(pred, target) -> Tensor:
    """The paper's photometric error |I_t(p) - Î_s(p)|, mean over the colours.

    pred, target (N, C, H, W) -> (N, 1, H, W).
    """
    pred, target = ag.as_tensor(pred), ag.as_tensor(target)
    return ag.mean(ag.abs(pred - target), axis=1, keepdims=True)


def reconstruction_errors(target, sources, depth, T, K, error=l1_error):
    """error(Î_s(p), I_t(p)) for every source s and target pixel p.

    Î_s is source s warped into the target view by Eq. 3 (``inverse_warp`` with
    border padding: a point projected outside the source reads its nearest edge pixel).
    With ``error = l1_error``, the sum of the result over s and p is the paper's L_vs.

    Args:
        target: (N, 3, h, w) array; sources: list of S arrays like it.
        depth: (N, 1, h, w) Tensor, D_t; T: (S N, 4, 4) Tensor, T_{t->s} in (s, n) order.
        K: (3, 3) intrinsics of (h, w) images; error: (pred, target) -> (M, 1, h, w).

    Returns:
        (errors, valid): errors (S, N, 1, h, w) Tensor; valid (S, N, 1, h, w) array, 1
        where p_s falls inside source s.
    """
    n, _, h, w = target.shape
    s_count = len(sources)
    depth_all = ag.concat([depth] * s_count, axis=0) if s_count > 1 else depth
    warped, valid = inverse_warp(np.concatenate(sources, axis=0), depth_all, T, K, "border")
    err = error(warped, Tensor(np.concatenate([target] * s_count, axis=0)))
    return ag.reshape(err, (s_count, n, 1, h, w)), valid.reshape(s_count, n, 1, h, w)


# -- our additions (module docstring) -----------------------------------------------------
SSIM_C1, SSIM_C2 = 0.01 ** 2, 0.03 ** 2
INVALID = 1.0e3         # added to the error of out-of-view pixels so the minimum skips them
SMOOTH_WEIGHT = 1e-3    # lambda (monodepth2)
SPEED_WEIGHT = 0.1      # mu (ours)
STEP = SPEED * FRAME_DT  # metres flown between frames: 2 m/s x 0.4 s (the paper's)


@dataclass
class LossConfig:
    """The settings of the view-synthesis loss (module docstring)."""
    ssim_weight: float = setting(0.85, "alpha of the SSIM term in the photometric error "
                                       "(monodepth2: 0.85; 0: the paper's plain L1)",
                                 source="ours", check=between(0.0, 1.0))
    unmasked_weight: float = setting(0.0, "beta of the unmasked photometric term beside the "
                                           "auto-mask (0: none)", source="ours",
                                     check=at_least(0.0))
    full_res: bool = setting(False, "warp the full-size images with every scale's "
                                    "disparity upsampled (monodepth2), not images "
                                    "downsampled to the scale (SfMLearner)", source="ours")

    def __post_init__(self):
        validate(self)


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
    """[SSIM] pe = alpha (1 - SSIM)/2 + (1 - alpha) |pred - target|, mean over channels.

    pred, target (N, C, H, W) -> (N, 1, H, W); alpha = 0 gives ``l1_error``.
    """
    err = l1_error(pred, target)
    if ssim_weight > 0:
        ssim = ag.mean(ssim_dissimilarity(pred, target), axis=1, keepdims=True)
        err = ssim * ssim_weight + err * (1.0 - ssim_weight)
    return err


def configured_error(cfg: LossConfig):
    """pe with the configured alpha, as a function (pred, target) -> (N, 1, H, W)."""
    return lambda pred, target: photometric_error(pred, target, cfg.ssim_weight)


def masked_minimum(errors, valid, identity, unmasked_weight: float = 0.0):
    """[min], [auto-mask], [unmasked]: the photometric term of one scale.

    errors (S, N, 1, h, w) Tensor and valid (S, N, 1, h, w) from
    ``reconstruction_errors``; identity (N, 1, h, w) array, min_s pe(I_t, I_s) of the
    unwarped sources. Returns (scalar Tensor, mask (N, 1, h, w): 1 where the warp wins).
    """
    masked = errors + INVALID * (1.0 - valid)      # an out-of-view source never wins
    best = crop(masked, (0,))
    for s in range(1, errors.shape[0]):
        best = ag.minimum(best, crop(masked, (s,)))                          # (N, 1, h, w)
    photo = ag.mean(ag.minimum(best, identity))
    if unmasked_weight > 0:
        photo = photo + ag.mean(ag.minimum(best, 1.0)) * unmasked_weight
    return photo, (best.data < identity).astype(identity.dtype)


def downsample_image(image: np.ndarray, factor: int) -> np.ndarray:
    """Area-average (N, C, H, W) by ``factor`` (H, W divisible by it); NumPy, no grad."""
    if factor == 1:
        return image
    n, c, h, w = image.shape
    if h % factor or w % factor:
        raise ValueError(f"downsample_image: {h}x{w} is not divisible by {factor}")
    return image.reshape(n, c, h // factor, factor, w // factor, factor).mean(axis=(3, 5))


def smoothness_loss(disp, image) -> Tensor:
    """[smooth] mean |dx d*| w_x + mean |dy d*| w_y with d* = disp / mean(disp) per image.

    disp (N, 1, h, w) Tensor, image (N, C, h, w) array. w = exp(-mean_c |grad I|): the
    disparity may bend where the image has an edge (edge-aware).
    """
    disp = ag.as_tensor(disp)
    a = slice(None)
    d = disp * (1.0 / (ag.mean(disp, axis=(2, 3), keepdims=True) + 1e-7))
    dx = crop(d, (a, a, a, slice(1, None))) - crop(d, (a, a, a, slice(0, -1)))
    dy = crop(d, (a, a, slice(1, None))) - crop(d, (a, a, slice(0, -1)))
    image = np.asarray(image, dtype=disp.dtype)
    wx = np.exp(-np.abs(np.diff(image, axis=3)).mean(axis=1, keepdims=True))
    wy = np.exp(-np.abs(np.diff(image, axis=2)).mean(axis=1, keepdims=True))
    return ag.mean(ag.abs(dx) * wx) + ag.mean(ag.abs(dy) * wy)


def at_scale(target, sources, disp, K, factor: int, full_res: bool):
    """[scales] (target, sources, depth, K) of the scale of ``disp`` (1 / ``factor`` of
    the images). SfMLearner: the images downsampled to the disparity's size, K scaled;
    ``full_res`` (monodepth2): the disparity upsampled to the images, which stay whole."""
    if full_res:
        depth = 1.0 / (disp if factor == 1 else upsample(disp, factor, "bilinear"))
        return target, sources, depth, K
    return (downsample_image(target, factor), [downsample_image(s, factor) for s in sources],
            1.0 / disp, scale_intrinsics(K, 1.0 / factor))


def speed_loss(poses, step: float = STEP) -> Tensor:
    """[speed] mean over images and sources of | |t_{t->s}| - step |; poses (N, S, 6)."""
    t = crop(poses, (slice(None), slice(None), slice(0, 3)))
    norm = ag.sqrt(ag.sum(t * t, axis=2) + 1e-12)
    return ag.mean(ag.abs(norm - np.full(poses.shape[1], step, dtype=poses.dtype)))


# -- the loss we train with -----------------------------------------------------------------
def view_synthesis_loss(target, sources, disps, poses, K, config: LossConfig | None = None,
                        photometric_error=None):
    """L = L_photo + lambda L_smooth + mu L_speed (module docstring) for one batch.

    Args:
        target: (N, 3, H, W) float array in [0, 1].
        sources: list of S arrays (N, 3, H, W), the neighbours of the target.
        disps: list of disparity Tensors, scale i of shape (N, 1, H / 2^i, W / 2^i).
        poses: (N, S, 6) Tensor of pose vectors T_{t->s}.
        K: (3, 3) intrinsics of the (H, W) images.
        photometric_error: (pred, target) -> (M, 1, h, w) Tensor, the per-pixel error
            (default: pe with ``config.ssim_weight``; ``l1_error`` is the paper's).

    Returns:
        (loss, info): a scalar Tensor and a dict of floats (photo, smooth, mask, speed).
    """
    cfg = config or LossConfig()
    pe = photometric_error or configured_error(cfg)
    target = np.asarray(target.data if isinstance(target, Tensor) else target)
    n, _, h, w = target.shape
    sources = [np.asarray(s.data if isinstance(s, Tensor) else s, dtype=target.dtype)
               for s in sources]
    if not sources or any(s.shape != target.shape for s in sources):
        raise ValueError(f"view_synthesis_loss: needs source frames shaped like the target "
                         f"{target.shape}; got {[s.shape for s in sources]}")
    poses = ag.as_tensor(poses)
    if poses.shape != (n, len(sources), 6):
        raise ValueError(f"view_synthesis_loss: poses must be (N, S, 6) = "
                         f"{(n, len(sources), 6)}; got {poses.shape}")
    # Pose matrices for every (source, image): batch order (s, n).
    T = pose_vec_to_mat(ag.reshape(ag.transpose(poses, (1, 0, 2)), (len(sources) * n, 6)))
    photos, smooths, masks = [], [], []
    for i, disp in enumerate(disps):
        factor = 2 ** i
        if disp.shape != (n, 1, -(-h // factor), -(-w // factor)):
            raise ValueError(f"view_synthesis_loss: disps[{i}] must be (N, 1, H/{factor}, "
                             f"W/{factor}) = {(n, 1, h // factor, w // factor)}; got "
                             f"{disp.shape}")
        tgt_i, srcs_i, depth, K_i = at_scale(target, sources, disp, K, factor, cfg.full_res)
        errors, valid = reconstruction_errors(tgt_i, srcs_i, depth, T, K_i, pe)
        identity = pe(Tensor(np.concatenate(srcs_i)),            # the unwarped sources
                      Tensor(np.concatenate([tgt_i] * len(srcs_i)))).data
        identity = identity.reshape(errors.shape).min(axis=0).astype(target.dtype)
        photo_i, mask_i = masked_minimum(errors, valid, identity, cfg.unmasked_weight)
        photos.append(photo_i)
        masks.append(mask_i.ravel())
        smooths.append(smoothness_loss(disp, downsample_image(target, factor))
                       * (1.0 / factor))
    photo, smooth, speed = _mean(photos), _mean(smooths), speed_loss(poses)
    loss = photo + smooth * SMOOTH_WEIGHT + speed * SPEED_WEIGHT
    info = {"photo": float(photo.data), "smooth": float(smooth.data),
            "mask": float(np.concatenate(masks).mean()), "speed": float(speed.data)}
    return loss, info


def _mean(terms: list) -> Tensor:
    total = terms[0]
    for term in terms[1:]:
        total = total + term
    return total * (1.0 / len(terms))
