"""Reference solution, exercise 7 (depth loss): SSIM + L1 with alpha = 0.85 (monodepth2)."""
from minid3rqn import autograd as ag
from minid3rqn.depth.losses import ssim_dissimilarity

ALPHA = 0.85


def photometric_error(pred, target):
    l1 = ag.mean(ag.abs(pred - target), axis=1, keepdims=True)
    ssim = ag.mean(ssim_dissimilarity(pred, target), axis=1, keepdims=True)
    return ssim * ALPHA + l1 * (1.0 - ALPHA)
