"""Depth inference (``DepthEstimator``) and evaluation against ground truth.

Depth metrics (Eigen et al. 2014, the SfMLearner / monodepth2 protocol). For each
image the prediction is first scaled by median(D_gt) / median(D_pred) (monocular depth
is known only up to scale), then clipped to [min_depth, max_depth]; over all pixels:

    abs rel   = mean |d - d*| / d*              sq rel = mean (d - d*)^2 / d*
    RMSE      = sqrt(mean (d - d*)^2)           RMSE log = sqrt(mean (ln d - ln d*)^2)
    delta_k   = fraction of pixels with max(d / d*, d* / d) < 1.25^k,  k = 1, 2, 3

(d predicted, d* ground truth). The same metrics are also reported with the
estimator's own scale (from the known flight speed, no GT): ``*_speed_scale``.

Pose: for every triplet and source, the predicted T_{t->s} against the GT relative
transform: translation error |t_pred s - t_gt| with s the per-snippet least-squares
scale (SfMLearner's ATE on 3-frame snippets), and rotation error, the angle of
R_pred^T R_gt in degrees.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .. import autograd as ag
from ..io import load_npz, save_npz
from ..nets.dispnet import DispNet
from ..nets.fast import DispNetInference
from ..world.geometry import relative_transform
from .cost_volume import plane_sweep_cost, sweep_depths
from .data import Sequence
from .geometry import pose_vec_to_mat

METRICS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")


class DepthEstimator:
    """Monocular depth for the RL agent: RGB frames in, depth maps (metres) out.

    Scale convention: monocular depth is known only up to a global scale. This
    estimator fixes it once, at training time, from the drone's known forward speed
    (0.8 m between frames, see ``train.speed_scale``), so ``predict`` returns depth in
    approximately metres: depth = scale / disp. The scale is a constant of the model
    file, the same for every frame, so depth maps from one model are comparable across
    frames and episodes. Consumers that want a unit-free input can divide by a fixed
    constant (e.g. 10 m); do not normalise per frame, which would throw away the
    absolute nearness that obstacle avoidance needs.

    Inference runs on a snapshot of the network's weights, taken at the first
    ``predict`` (the graph-free ``DispNetInference``); call ``refresh()`` if the network
    is trained further while the estimator is kept.

    Args:
        dispnet: a trained DispNet.
        scale: metres per unit of 1 / disp.
        meta: free-form metadata (command, seed, results) from the model file.
        flip: test-time flip averaging (monodepth's post-processing, in its plain form):
            the disparity is the mean of the network's disparity for the frame and,
            flipped back, for the frame mirrored left-right. A left-right mirror of a
            world is as likely as the world, so the network's errors on the two views
            are partly independent and the mean is closer to the truth (docs/depth.md
            section 7, "Test-time flip"). Twice the inference cost; off by default, and
            not used in training.
    """

    def __init__(self, dispnet: DispNet, scale: float = 1.0, meta: dict | None = None,
                 flip: bool = False):
        self.net, self.scale, self.meta = dispnet, float(scale), meta or {}
        self.flip = bool(flip)
        self._fast = None                   # DispNetInference, built at the first predict
        self.height = self.meta.get("height", 32)
        self.width = self.meta.get("width", 104)
        self.in_frames = getattr(dispnet, "in_frames", 1)   # 2: also reads the previous frame
        self.cost_planes = getattr(dispnet, "cost_planes", 0)  # D: a plane-sweep cost volume

    @property
    def needs_previous(self) -> bool:
        """Whether ``predict`` needs the frames filmed one step before (``prev``): a
        two-frame DispNet, or one with a cost volume (which also needs ``motion``)."""
        return self.in_frames == 2 or self.cost_planes > 0

    @property
    def horizon_row(self) -> float:
        """The horizon row of the frames it was trained on (train-depth --horizon-row;
        files written before that option existed: the middle row)."""
        return float(self.meta.get("horizon_row", (self.height - 1) / 2.0))

    # -- files -----------------------------------------------------------------------
    def save(self, path, extra: dict | None = None) -> Path:
        kept = {"K": self.meta["K"]} if "K" in self.meta else {}   # a cost volume's camera
        meta = {"dispnet": self.net.config(), "scale": self.scale,
                "height": self.height, "width": self.width, **kept, **(extra or {})}
        self.meta = meta
        state = {k: v.astype(np.float32) for k, v in self.net.state_dict().items()}
        return save_npz(path, state, meta)

    @classmethod
    def load(cls, path, flip: bool = False) -> "DepthEstimator":
        """A model file written by ``save`` (or a train-depth checkpoint); ``flip``: see
        the class doc."""
        est = cls._load(path)
        est.flip = bool(flip)
        return est

    @classmethod
    def _load(cls, path) -> "DepthEstimator":
        arrays, meta = load_npz(path)
        if meta and "config" in meta and "iteration" in meta:       # a training checkpoint
            from .train import TrainConfig
            cfg = TrainConfig.from_dict(meta["config"])
            net = DispNet(cfg.encoder, cfg.decoder, cfg.n_scales,
                          in_frames=2 if cfg.prev_frame else 1,
                          cost_planes=cfg.cost_volume)
            net.load_state_dict({k[5:]: v for k, v in arrays.items() if k.startswith("disp.")})
            # With the known-speed term the network's depth is already in metres.
            kept = {k: meta[k] for k in ("iteration", "horizon_row", "K") if k in meta}
            return cls(net, 1.0, kept)
        if not meta or "dispnet" not in meta:
            raise ValueError(f"DepthEstimator.load: {str(path)!r} is not a depth model file "
                             f"(no 'dispnet' metadata); write one with train-depth")
        c = meta["dispnet"]
        net = DispNet(tuple(c["encoder"]), tuple(c["decoder"]), c["n_scales"],
                      c["disp_scale"], c["min_disp"], c.get("double_conv", True),
                      in_frames=c.get("in_frames", 1), cost_planes=c.get("cost_planes", 0))
        net.load_state_dict(arrays)
        return cls(net, meta.get("scale", 1.0), meta)

    # -- inference -------------------------------------------------------------------
    # ``predict`` runs ``DispNetInference`` (nets/fast.py): a graph-free copy of the
    # network's weights, plain NumPy, finest scale only, the same convolution routine as
    # the autograd path; ~2.5x faster at batch 1 (the flight loop), ~2x on batches.
    # Training, and anything that needs gradients, uses ``self.net`` (DispNet.forward).
    def refresh(self) -> None:
        """Re-read the network's weights on the next ``predict`` (after changing them:
        ``predict`` works on a snapshot taken at its first call)."""
        self._fast = None

    def _frames(self, rgb) -> tuple[np.ndarray, bool]:
        """rgb as checked uint8 (N, H, W, 3), and whether it was a single (H, W, 3)."""
        rgb = np.asarray(rgb)
        single = rgb.ndim == 3
        if single:
            rgb = rgb[None]
        if rgb.ndim != 4 or rgb.shape[-1] != 3:
            raise ValueError(f"DepthEstimator: rgb must be (N, H, W, 3) uint8; got {rgb.shape}")
        if rgb.shape[1:3] != (self.height, self.width):
            raise ValueError(f"DepthEstimator: the model was trained on {self.height}x"
                             f"{self.width} images; got {rgb.shape[1]}x{rgb.shape[2]}")
        if rgb.dtype != np.uint8:
            raise TypeError(f"DepthEstimator: rgb must be uint8 (0..255); got {rgb.dtype}")
        return rgb, single

    def _input(self, rgb, prev, motion=None) -> tuple[np.ndarray, bool]:
        """The network's channels-last input: the checked frames; with a two-frame
        DispNet the previous frames after them on channels (N, H, W, 6); with a cost
        volume, the frames as floats in [0, 1] and the D cost planes after them
        (N, H, W, 3 + D)."""
        rgb, single = self._frames(rgb)
        if not self.needs_previous:
            if prev is not None or motion is not None:
                raise ValueError("DepthEstimator: this model reads one frame; prev and "
                                 "motion (the previous frames and the motion since) are for "
                                 "a two-frame model (train-depth --prev-frame) or one with a "
                                 "cost volume (--cost-volume)")
            return rgb, single
        kind = ("reads two frames (train-depth --prev-frame)" if self.in_frames == 2 else
                "reads a cost volume (train-depth --cost-volume)")
        if prev is None:
            raise ValueError(f"DepthEstimator: this model {kind}: give prev, the frames "
                             f"filmed one step before rgb")
        prev, _ = self._frames(prev)
        if prev.shape != rgb.shape:
            raise ValueError(f"DepthEstimator: prev must have rgb's shape {rgb.shape}; got "
                             f"{prev.shape}")
        x = np.concatenate([rgb, prev], axis=-1) if self.in_frames == 2 else rgb
        if not self.cost_planes:
            if motion is not None:
                raise ValueError("DepthEstimator: motion is for a model with a cost volume "
                                 "(train-depth --cost-volume); this one reads prev only")
            return x, single
        if motion is None:
            raise ValueError(f"DepthEstimator: this model {kind}: give motion, T_{{t->t-1}} "
                             f"(N, 4, 4), e.g. world.geometry.relative_transform(pose, "
                             f"previous pose)")
        motion = np.asarray(motion, dtype=np.float64)
        if motion.ndim == 2:
            motion = motion[None]
        cost = plane_sweep_cost(rgb, prev, motion, self.K, sweep_depths(self.cost_planes))
        return np.concatenate([x * np.float32(1 / 255.0), cost], axis=-1), single

    @property
    def K(self) -> np.ndarray:
        """The intrinsics of the frames the model was trained on, from its file (``K``):
        the cost volume warps with them."""
        if "K" in self.meta:
            return np.asarray(self.meta["K"], dtype=np.float64)
        raise ValueError("DepthEstimator: this model file has no intrinsics 'K' in its "
                         "metadata, which its cost volume needs; train-depth writes them")

    def sequence_targets(self, seq: Sequence, idx=None, with_previous: bool = False
                         ) -> np.ndarray:
        """The frames of ``seq`` (of ``idx``, default all) this model can predict: all of
        them, or for a two-frame model (or with ``with_previous``, to score a one-frame
        model on the same frames) those with a previous frame in their flight."""
        idx = np.arange(len(seq)) if idx is None else np.asarray(idx)
        if not self.needs_previous and not with_previous:
            return idx
        return idx[(idx > 0) & (seq.flight[np.maximum(idx - 1, 0)] == seq.flight[idx])]

    def predict_sequence(self, seq: Sequence, idx) -> np.ndarray:
        """Depth (N, H, W) of the frames ``idx`` of ``seq`` (each with its previous frame,
        for a two-frame or cost-volume model: ``sequence_targets`` lists the frames that
        have one; a cost volume also takes the motion between them from ``seq.pose``,
        the odometry of the flight)."""
        idx = np.asarray(idx)
        if not self.needs_previous:
            return self.predict(seq.rgb[idx])
        ok = self.sequence_targets(seq, idx)
        if len(ok) != len(idx):
            raise ValueError("DepthEstimator.predict_sequence: a two-frame or cost-volume "
                             "model needs the previous frame of each frame in its flight; "
                             "pick the frames with sequence_targets")
        return self.predict(seq.rgb[idx], prev=seq.rgb[idx - 1],
                            motion=self.sequence_motion(seq, idx))

    def sequence_motion(self, seq: Sequence, idx) -> np.ndarray | None:
        """T_{t->t-1} (N, 4, 4) of the frames ``idx`` of ``seq`` for a cost-volume model
        (None for others): the relative transform of the poses filmed."""
        if not self.cost_planes:
            return None
        if seq.pose is None:
            raise ValueError("DepthEstimator: a cost-volume model needs the motion between "
                             "frames; this sequence has no poses")
        idx = np.asarray(idx)
        return relative_transform(seq.pose[idx], seq.pose[idx - 1])

    def predict_disp(self, rgb, batch_size: int = 64, prev=None, motion=None) -> np.ndarray:
        """rgb uint8 (N, H, W, 3) or (H, W, 3) -> network disparity (N, H, W) float32.

        Equal (to float32 round-off) to ``predict_disp_autograd``, the autograd forward
        ``net(rgb as (N, 3, H, W) float32 / 255, scales=1)[0]``; computed by the
        graph-free ``DispNetInference``. ``batch_size`` is kept for compatibility (the
        inference path runs its own chunks). With ``flip``: the mean of that and its value
        on the mirrored frames, mirrored back (for a cost volume, mirroring its planes is
        the same as building it from the mirrored frames and motion). ``prev``: the
        frames before ``rgb``, for a two-frame or cost-volume model (and only for one);
        ``motion``: T_{t->t-1} (N, 4, 4), for a cost-volume model.
        """
        rgb, single = self._input(rgb, prev, motion)
        if self._fast is None:
            self._fast = DispNetInference(self.net)
        out = self._fast(rgb).astype(np.float32, copy=False)
        if self.flip:
            mirrored = self._fast(np.ascontiguousarray(rgb[:, :, ::-1]))
            out = 0.5 * (out + mirrored[:, :, ::-1].astype(np.float32, copy=False))
        return out[0] if single else out

    def predict_disp_autograd(self, rgb, batch_size: int = 64, prev=None, motion=None
                              ) -> np.ndarray:
        """``predict_disp`` through the autograd forward (``DispNet.forward`` under
        ``no_grad``), as it was computed before the inference path: the reference for
        tests and benchmarks."""
        rgb, single = self._input(rgb, prev, motion)
        unit = 1 / 255.0 if rgb.dtype == np.uint8 else 1.0     # a cost-volume input: floats
        out = np.empty(rgb.shape[:3], dtype=np.float32)
        with ag.no_grad():
            for k in range(0, len(rgb), batch_size):
                x = rgb[k:k + batch_size].transpose(0, 3, 1, 2).astype(np.float32) * unit
                out[k:k + batch_size] = self.net(x, scales=1)[0].data[:, 0]
        return out[0] if single else out

    def predict(self, rgb, batch_size: int = 64, prev=None, motion=None) -> np.ndarray:
        """rgb uint8 (N, H, W, 3) -> depth float32 (N, H, W) in metres (see class doc);
        a two-frame model also needs ``prev``, the frames filmed one step before, and a
        cost-volume model ``prev`` and ``motion``, T_{t->t-1} (N, 4, 4)."""
        return (self.scale / self.predict_disp(rgb, batch_size, prev, motion)
                ).astype(np.float32)


# -- metrics -----------------------------------------------------------------------------
def align_to_gt(pred, gt, min_depth: float = 0.1, max_depth: float = 50.0,
                median_scaling: bool = True, name: str = "depth_metrics"):
    """The evaluation protocol's first step, shared by every depth metric here.

    (N, H, W) inputs -> ``(p, g, ok)``: float64 copies, ``ok`` the pixels with a valid GT
    depth (min_depth < g < max_depth), and ``p`` the prediction scaled per image by
    median(g[ok]) / median(p[ok]) (SfMLearner's protocol; skipped with
    ``median_scaling=False``, to judge the model's own metric scale), then clipped to
    [min_depth, max_depth]. A frame without a valid pixel (a camera against a wall: every
    GT depth under ``min_depth``) keeps its scale of 1 and is scored nowhere, like any
    invalid pixel; if no frame has a valid pixel, ``ValueError``.
    """
    p = np.asarray(pred, dtype=np.float64)
    g = np.asarray(gt, dtype=np.float64)
    if p.shape != g.shape or p.ndim != 3:
        raise ValueError(f"{name}: pred {p.shape} and gt {g.shape} must be the same "
                         f"(N, H, W) shape")
    ok = (g > min_depth) & (g < max_depth) & np.isfinite(g)
    if not ok.any():
        raise ValueError(f"{name}: no pixel has a GT depth in ({min_depth:g}, {max_depth:g}) m "
                         f"in any of the {len(g)} frames; nothing to score")
    if median_scaling:
        scale = np.array([np.median(gi[m]) / np.median(pi[m]) if m.any() else 1.0
                          for pi, gi, m in zip(p, g, ok)])
        p = p * scale[:, None, None]
    return np.clip(p, min_depth, max_depth), g, ok


def depth_metrics(pred, gt, min_depth: float = 0.1, max_depth: float = 50.0,
                  median_scaling: bool = True) -> dict:
    """The seven metrics (module docstring), averaged over images; (N, H, W) inputs."""
    p, g, ok = align_to_gt(pred, gt, min_depth, max_depth, median_scaling)
    rows = []
    for pi, gi in ((pi[m], gi[m]) for pi, gi, m in zip(p, g, ok) if m.any()):
        ratio = np.maximum(pi / gi, gi / pi)
        rows.append([np.mean(np.abs(pi - gi) / gi), np.mean((pi - gi) ** 2 / gi),
                     np.sqrt(np.mean((pi - gi) ** 2)),
                     np.sqrt(np.mean((np.log(pi) - np.log(gi)) ** 2)),
                     np.mean(ratio < 1.25), np.mean(ratio < 1.25 ** 2),
                     np.mean(ratio < 1.25 ** 3)])
    return dict(zip(METRICS, np.mean(rows, axis=0).tolist()))


DEPTH_BINS = (0.0, 2.0, 4.0, 7.0, 12.0, 50.0)


COLUMNS = ("all", "centre", "sides")


def errors_by_depth(pred, gt, bins=DEPTH_BINS, median_scaling: bool = True,
                    columns: str = "all") -> list[dict]:
    """Where the errors are: per GT-depth bin, the share of pixels, the mean abs rel and
    the mean signed relative error (pred - gt) / gt (> 0: too far), after the same
    alignment as ``depth_metrics`` (per-image median scaling, or with
    ``median_scaling=False`` the model's own metric scale). (N, H, W) inputs.

    ``columns``: "all", "centre" (the middle half of the image width: what lies ahead,
    where a collision comes from) or "sides" (the outer quarters: what the drone passes).
    Shares are of the pixels in those columns."""
    if columns not in COLUMNS:
        raise ValueError(f"errors_by_depth: columns must be one of {COLUMNS}; got {columns!r}")
    p, g, ok = align_to_gt(pred, gt, median_scaling=median_scaling, name="errors_by_depth")
    if columns != "all":
        w = g.shape[-1]
        centre = np.zeros(w, bool)
        centre[w // 4: w - w // 4] = True
        ok = ok & (centre if columns == "centre" else ~centre)
    rel = (p - g) / np.where(ok, g, 1.0)
    out = []
    for lo, hi in zip(bins[:-1], bins[1:]):
        m = ok & (g >= lo) & (g < hi)
        out.append({"from_m": lo, "to_m": hi, "share": float(m.sum() / ok.sum()),
                    "abs_rel": float(np.abs(rel[m]).mean()) if m.any() else float("nan"),
                    "signed_rel": float(rel[m].mean()) if m.any() else float("nan")})
    return out


Q_NET_RANGE = (0.5, 10.0)  # metres: the depth range a Q-net reads (rl.flights clips at 10 m)


def log_error_parts(depth, estimate, clip=Q_NET_RANGE) -> dict:
    """How a depth error is laid out: e = ln(estimate / depth) of frames (F, H, W),
    split as

        e(f, v, u) = a(f) + b(f, u) + c(f, v) + r(f, v, u):

    a the frame's mean, b the column means of e - a, c the row means of e - a - b, and
    r the rest. Returns the std of e and of each part (pixels weighted alike), and the
    mean of e. Both depths are clipped to ``clip`` first (0.5 to 10 m, the range a
    Q-net reads). Used for the DispNet's error in flight
    (examples/07_which_depth_errors_matter.py) and for a student's corruption
    (classroom exercise 8)."""
    lo, hi = clip
    e = np.log(np.clip(np.asarray(estimate, np.float64), lo, hi) /
               np.clip(np.asarray(depth, np.float64), lo, hi))
    if e.ndim != 3:
        raise ValueError(f"log_error_parts: depth and estimate must be (frames, rows, "
                         f"columns); got shape {e.shape}")
    a = e.mean(axis=(1, 2), keepdims=True)
    b = (e - a).mean(axis=1, keepdims=True)
    c = (e - a - b).mean(axis=2, keepdims=True)
    rest = e - a - b - c
    return {"total": float(e.std()), "per frame": float(a.std()),
            "per column": float(b.std()), "per row": float(c.std()),
            "rest": float(rest.std()), "mean": float(e.mean())}


def pose_errors(posenet, seq: Sequence, max_triplets: int = 500) -> dict:
    """Translation (scale-aligned per snippet, metres) and rotation (degrees) errors of a
    PoseNet of the (previous, next) sources."""
    if seq.pose is None:
        raise ValueError("pose_errors: the sequence has no GT poses")
    if posenet.n_sources != 2:
        raise ValueError(f"pose_errors: needs a PoseNet of the previous and next frames; "
                         f"this one reads {posenet.n_sources} sources")
    idx = seq.triplet_indices()
    if len(idx) > max_triplets:
        idx = idx[np.linspace(0, len(idx) - 1, max_triplets).astype(int)]
    t_err, r_err, t_gt_norm = [], [], []
    with ag.no_grad():
        for k in range(0, len(idx), 64):
            tg = idx[k:k + 64]
            target, sources = seq.batch(tg)
            vec = posenet(target, sources).data.astype(np.float64)              # (B, 2, 6)
            T_pred = pose_vec_to_mat(vec.reshape(-1, 6)).data.reshape(len(tg), 2, 4, 4)
            T_gt = np.stack([relative_transform(seq.pose[tg], seq.pose[tg + d])
                             for d in (-1, 1)], axis=1)
            tp, tt = T_pred[..., :3, 3], T_gt[..., :3, 3]                      # (B, 2, 3)
            s = (tp * tt).sum(axis=(1, 2)) / np.maximum((tp * tp).sum(axis=(1, 2)), 1e-12)
            t_err.append(np.linalg.norm(tp * s[:, None, None] - tt, axis=-1).ravel())
            t_gt_norm.append(np.linalg.norm(tt, axis=-1).ravel())
            R = np.einsum("bsji,bsjk->bsik", T_pred[..., :3, :3], T_gt[..., :3, :3])
            cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1)
            r_err.append(np.degrees(np.arccos(cos)).ravel())
    t_err, r_err = np.concatenate(t_err), np.concatenate(r_err)
    return {"trans_err_m": float(t_err.mean()), "trans_err_rel": float(
        t_err.mean() / np.concatenate(t_gt_norm).mean()), "rot_err_deg": float(r_err.mean())}


def horizon_band(K, height: int, above: float, below: float) -> np.ndarray:
    """(H,) bool: the image rows v from ``above`` rows above the horizon (row cy = K[1, 2])
    to ``below`` rows below it, -above <= v - cy <= below. Two cameras with different
    horizon rows (``Camera.horizon_row``) see the same band of directions there, so
    their depth can be scored on the same part of the world."""
    if above < 0 or below < 0:
        raise ValueError(f"horizon_band: above and below must be >= 0 rows; got "
                         f"{above}, {below}")
    off = np.arange(height) - float(K[1, 2])
    rows = (off >= -above) & (off <= below)
    if not rows.any():
        raise ValueError(f"horizon_band: no image row lies from {above} rows above to "
                         f"{below} below the horizon (row {float(K[1, 2]):g} of {height})")
    return rows


def evaluate(estimator: DepthEstimator, seq: Sequence, posenet=None,
             max_frames: int | None = None, rows=None, with_previous: bool = False) -> dict:
    """Depth metrics (median-scaled and speed-scaled) on ``seq``; pose errors if given.
    ``rows``: (H,) bool, score only these image rows (the network sees whole frames;
    the median scaling uses the scored pixels), e.g. ``horizon_band``. A two-frame model
    is scored on the frames with a previous frame in their flight; ``with_previous``
    scores any model on those frames only. For a two-frame model, ``prev_frame_effect``
    says how much it reads the previous frame: the mean |ln(depth / depth with the frame
    itself given as its previous one)|, 0 for a network that ignores it; and
    ``prev_kernel_ratio``, the size of its first convolution's kernels for the previous
    frame over those for the frame itself."""
    if seq.depth is None:
        raise ValueError("evaluate: the sequence has no GT depth")
    two = getattr(estimator, "needs_previous", False)
    idx = estimator.sequence_targets(seq, with_previous=with_previous) \
        if (two or with_previous) else np.arange(len(seq))
    if max_frames and len(idx) > max_frames:
        idx = idx[np.linspace(0, len(idx) - 1, max_frames).astype(int)]
    pred = estimator.predict_sequence(seq, idx) if two else estimator.predict(seq.rgb[idx])
    gt = seq.depth[idx]
    if rows is not None:
        pred, gt = pred[:, rows], gt[:, rows]
    out = {"frames": int(len(idx))}
    if two:     # how much the previous frame moves the prediction: the same frames with
        still = estimator.predict(seq.rgb[idx], prev=seq.rgb[idx],   # no motion at all
                                  motion=estimator.sequence_motion(seq, idx))
        full = pred if rows is None else estimator.predict_sequence(seq, idx)
        out["prev_frame_effect"] = float(np.mean(np.abs(np.log(full / still))))
        w = estimator.net.enc_a[0].weight.data    # (out, 3 + 3 or D, 3, 3): frame, the rest
        out["prev_kernel_ratio"] = float(np.linalg.norm(w[:, 3:]) / np.linalg.norm(w[:, :3]))
    out.update(depth_metrics(pred, gt))
    out.update({f"{k}_speed_scale": v for k, v in
                depth_metrics(pred, gt, median_scaling=False).items()})
    if posenet is not None and seq.pose is not None:
        if posenet.n_sources == 2:
            out.update(pose_errors(posenet, seq))
        else:      # a PoseNet of other sources (--source-offsets) has no GT to meet here
            out.update({k: float("nan") for k in ("trans_err_m", "trans_err_rel",
                                                  "rot_err_deg")})
    return out


# -- pictures ----------------------------------------------------------------------------
def comparison_picture(rgb, pred, gt, path, zoom: int = 3, gap: int = 3) -> Path:
    """Rows of RGB | predicted depth (median-scaled) | GT depth, written as a PNG."""
    from PIL import Image

    from ..viz import depth_to_rgb
    rows = []
    for im, p, g in zip(rgb, pred, gt):
        p = p * (np.median(g) / np.median(p))
        lo, hi = max(float(np.percentile(g, 1)), 0.1), float(np.percentile(g, 99))
        white = np.full((im.shape[0], gap, 3), 255, np.uint8)
        rows.append(np.concatenate([im, white, depth_to_rgb(p, lo, hi, log=True), white,
                                    depth_to_rgb(g, lo, hi, log=True)], axis=1))
        rows.append(np.full((gap, rows[-1].shape[1], 3), 255, np.uint8))
    img = np.concatenate(rows[:-1], axis=0)
    img = img.repeat(zoom, 0).repeat(zoom, 1)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path)
    return path


__all__ = ["METRICS", "DepthEstimator", "align_to_gt", "depth_metrics", "errors_by_depth",
           "pose_errors", "evaluate", "comparison_picture"]
