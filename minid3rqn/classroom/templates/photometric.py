"""Exercise 7: the photometric error of the depth loss. This file is the one place to change.

The depth network learns by view synthesis: a neighbouring frame is warped into the
target view with the predicted depth and motion, and the loss compares the warped
image with the target, pixel by pixel. The paper's Eq. 2 compares them with an L1
distance. Later work (Godard et al. 2017, monodepth2) adds a structural term, SSIM,
which compares local means, contrasts and correlations in 3x3 windows, so it is less
fooled by brightness changes and rewards matching texture:

    pe = alpha * (1 - SSIM(pred, target)) / 2 + (1 - alpha) * |pred - target|,  alpha = 0.85

Your task: switch from L1 to SSIM + L1, train the depth network with each, and
compare abs rel against ground truth.

    python -m minid3rqn check depth-loss
    python -m minid3rqn exercise depth-loss               (your error)
    python -m minid3rqn exercise depth-loss --baseline    (plain L1, the paper's Eq. 2)

``ssim_dissimilarity(pred, target)`` gives (1 - SSIM) / 2 per pixel and channel (or use
your own, built from autograd ops). Use only autograd ops (ag.mean, ag.abs, +, *) so
that gradients flow back into the depth network. The exercise hands your function to
the depth trainer, ``Trainer(frames, cfg, photometric_error=photometric_error)``, which
uses it wherever the loss compares two images (minid3rqn/depth/losses.py).
"""
from minid3rqn import autograd as ag
from minid3rqn.depth.losses import ssim_dissimilarity  # noqa: F401  (for your SSIM term)


def photometric_error(pred, target):
    """Per-pixel photometric error between the warped source and the target.

    Args:
        pred, target: Tensors (N, 3, H, W), colours in [0, 1].

    Returns:
        A Tensor (N, 1, H, W): the error at every pixel, averaged over the 3 colours.
    """
    return ag.mean(ag.abs(pred - target), axis=1, keepdims=True)    # L1: the paper's Eq. 2
