"""Unsupervised monocular depth (the paper's sensing module, SfMLearner-style).

- ``data``: scripted flights, sequence files, triplets of one flight.
- ``geometry``: pose vectors -> 4x4, the differentiable inverse warp.
- ``losses``: photometric (SSIM + L1, min over sources, auto-mask), smoothness, speed.
- ``train``: the loop with checkpoints and exact resume.
- ``evaluate``: ``DepthEstimator`` (inference for the RL agent) and GT metrics.
- ``commands``: the ``collect`` / ``train-depth`` / ``eval-depth`` command-line hooks.

See docs/depth.md.
"""
from .evaluate import DepthEstimator, depth_metrics, evaluate

__all__ = ["DepthEstimator", "depth_metrics", "evaluate"]
