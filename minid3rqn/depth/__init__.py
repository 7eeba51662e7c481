"""Unsupervised monocular depth (the paper's sensing module, SfMLearner-style).

- ``losses``: the paper's view-synthesis loss (Eq. 2, 3) first, then what we add.
- ``geometry``: pose vectors -> 4x4, the differentiable inverse warp (Eq. 3).
- ``data``: scripted flights (``CollectConfig``), sequence files, triplets of one flight.
- ``train``: the loop with checkpoints and exact resume; ``train_depth``, a whole run.
- ``evaluate``: ``DepthEstimator`` (inference for the RL agent) and GT metrics.
- ``commands``: the ``collect`` / ``train-depth`` / ``eval-depth`` command-line hooks.

See docs/depth.md.
"""
from .evaluate import DepthEstimator, depth_metrics, evaluate

__all__ = ["DepthEstimator", "depth_metrics", "evaluate"]
