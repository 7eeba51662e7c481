"""Ours, not the paper's: the DispNet's test-time flip (monodepth's post-processing).

A world mirrored left-right is as likely as the world, so the network's errors on a
frame and on its mirror image are partly independent. Averaging the two disparities
(the mirror's flipped back) removes part of them, at twice the cost:

    disp_flip(I) = (disp(I) + M disp(M I)) / 2,      M: reverse the image's columns

``evaluate --flip-tta`` and ``eval-depth --flip-tta`` fly or score a DispNet this way;
docs/depth.md section 7 and docs/results.md give what it changes.
"""
from __future__ import annotations

import numpy as np


class FlipAveraged:
    """A depth estimator (``depth.evaluate.DepthEstimator``) whose disparity is the
    mean of the estimator's on the frame and, flipped back, on the mirrored frame. Its
    ``scale`` (metres per unit of 1 / disp) and ``meta`` are the estimator's."""

    def __init__(self, estimator):
        self.estimator = estimator
        self.scale, self.meta = estimator.scale, estimator.meta

    def predict_disp(self, rgb) -> np.ndarray:
        """rgb uint8 (N, H, W, 3) or (H, W, 3) -> the averaged disparity, float32."""
        rgb = np.asarray(rgb)                           # width is the axis before colour
        disp = self.estimator.predict_disp(rgb)
        mirrored = self.estimator.predict_disp(np.ascontiguousarray(rgb[..., ::-1, :]))
        return 0.5 * (disp + mirrored[..., ::-1])

    def predict(self, rgb) -> np.ndarray:
        """rgb uint8 (N, H, W, 3) -> depth float32 (N, H, W) in metres: scale / disp."""
        return (self.scale / self.predict_disp(rgb)).astype(np.float32)
