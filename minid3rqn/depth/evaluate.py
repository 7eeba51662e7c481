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

import math
from pathlib import Path

import numpy as np

from .. import autograd as ag
from ..io import load_npz, reason, save_npz, write_file, write_image
from ..nets.dispnet import DispNet
from ..nets.module import check_finite
from ..world.geometry import relative_transform
from .data import Sequence
from .geometry import pose_vec_to_mat

METRICS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")


class DepthEstimator:
    """Monocular depth for the RL agent: RGB frames in, depth maps (metres) out.

    Scale: monocular depth is known only up to a global scale. This estimator fixes it
    once, at training time, from the drone's known forward speed (0.8 m between frames,
    ``train.speed_scale``), so ``predict`` returns depth = scale / disp in about metres,
    the same scale for every frame (not normalised per frame, which would throw away
    the absolute nearness that obstacle avoidance needs).

    Inference is ``DispNet.forward`` (finest scale) without a graph, on the network's
    current weights: training it further changes what ``predict`` returns.

    Args:
        dispnet: a trained DispNet.
        scale: metres per unit of 1 / disp.
        meta: free-form metadata (command, seed, results) from the model file.

    Our test-time flip (the mean with the mirrored frame's disparity) wraps an
    estimator: ``depth/flip.py: FlipAveraged``.
    """

    CHUNK = 32                              # frames per forward in ``predict_disp``

    def __init__(self, dispnet: DispNet, scale: float = 1.0, meta: dict | None = None):
        self.net, self.scale, self.meta = dispnet, float(scale), meta or {}
        self.height = self.meta.get("height", 32)
        self.width = self.meta.get("width", 104)

    # -- files -----------------------------------------------------------------------
    def save(self, path, extra: dict | None = None) -> Path:
        meta = {"dispnet": self.net.config(), "scale": self.scale,
                "height": self.height, "width": self.width, **(extra or {})}
        self.meta = meta
        state = {k: v.astype(np.float32) for k, v in self.net.state_dict().items()}
        return save_npz(path, state, meta)

    @classmethod
    def load(cls, path) -> "DepthEstimator":
        """A model file written by ``save``; ValueError naming the file if it is not one,
        or if a weight or the scale is not finite."""
        arrays, meta = load_npz(path)
        if not isinstance(meta, dict) or "dispnet" not in meta:
            raise ValueError(f"DepthEstimator.load: {str(path)!r} is not a depth model file "
                             f"(no 'dispnet' metadata); write one with train-depth")
        check_finite(arrays, path)
        try:
            c = meta["dispnet"]
            net = DispNet(tuple(c["encoder"]), tuple(c["decoder"]), c["n_scales"],
                          c["disp_scale"], c["min_disp"])
            net.load_state_dict(arrays)
            scale = float(meta.get("scale", 1.0))
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"DepthEstimator.load: {str(path)!r} is not a readable depth "
                             f"model: {reason(e)}") from None
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"DepthEstimator.load: {str(path)!r} records the scale {scale}; "
                             f"expected a number > 0")
        return cls(net, scale, meta)

    # -- inference -------------------------------------------------------------------
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

    def predict_disp(self, rgb) -> np.ndarray:
        """rgb uint8 (N, H, W, 3) or (H, W, 3) -> network disparity (N, H, W) float32:
        ``net(rgb as (N, 3, H, W) float32 / 255, scales=1)[0]`` under ``no_grad``, 32
        frames at a time (a bounded working set, about 1 MB per frame)."""
        rgb, single = self._frames(rgb)
        dtype = self.net.heads[0].weight.dtype
        out = np.empty(rgb.shape[:3], dtype)
        with ag.no_grad():
            for k in range(0, len(rgb), self.CHUNK):
                x = np.multiply(rgb[k:k + self.CHUNK], dtype.type(1 / 255.0))  # channels-last
                out[k:k + self.CHUNK] = self.net(x.transpose(0, 3, 1, 2), scales=1)[0].data[:, 0]
        out = out.astype(np.float32, copy=False)
        return out[0] if single else out

    def predict(self, rgb) -> np.ndarray:
        """rgb uint8 (N, H, W, 3) -> depth float32 (N, H, W) in metres (see class doc)."""
        return (self.scale / self.predict_disp(rgb)).astype(np.float32)


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


def errors_by_depth(pred, gt, bins=DEPTH_BINS) -> list[dict]:
    """Where the errors are: per GT-depth bin, the share of pixels, the mean abs rel and
    the mean signed relative error (pred - gt) / gt (> 0: too far), after the same
    alignment as ``depth_metrics`` (per-image median scaling). (N, H, W) inputs."""
    p, g, ok = align_to_gt(pred, gt, name="errors_by_depth")
    rel = (p - g) / np.where(ok, g, 1.0)
    out = []
    for lo, hi in zip(bins[:-1], bins[1:]):
        m = ok & (g >= lo) & (g < hi)
        out.append({"from_m": lo, "to_m": hi, "share": float(m.sum() / ok.sum()),
                    "abs_rel": float(np.abs(rel[m]).mean()) if m.any() else float("nan"),
                    "signed_rel": float(rel[m].mean()) if m.any() else float("nan")})
    return out


Q_NET_RANGE = (0.5, 10.0)  # metres: the depth range a Q-net reads (rl.observe clips at 10 m)


def log_error_parts(depth, estimate, clip=Q_NET_RANGE) -> dict:
    """How a depth error is laid out: e = ln(estimate / depth) of frames (F, H, W),
    split as

        e(f, v, u) = a(f) + b(f, u) + c(f, v) + r(f, v, u):

    a the frame's mean, b the column means of e - a, c the row means of e - a - b, and
    r the rest. Returns the std of e and of each part (pixels weighted alike), and the
    mean of e. Both depths are clipped to ``clip`` first (0.5 to 10 m, the range a
    Q-net reads)."""
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
    PoseNet of the (previous, next) sources; ``seq`` holds GT poses."""
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


def evaluate(estimator: DepthEstimator, seq: Sequence, posenet=None) -> dict:
    """Depth metrics of ``estimator`` on every frame of ``seq``, median-scaled and in its
    own (speed) scale (``*_speed_scale``); with ``posenet``, its pose errors too."""
    if seq.depth is None:
        raise ValueError("evaluate: the sequence has no GT depth")
    pred = estimator.predict(seq.rgb)
    out = {"frames": len(seq)}
    out.update(depth_metrics(pred, seq.depth))
    out.update({f"{k}_speed_scale": v for k, v in
                depth_metrics(pred, seq.depth, median_scaling=False).items()})
    if posenet is not None and seq.pose is not None:
        out.update(pose_errors(posenet, seq))
    return out


# -- pictures ----------------------------------------------------------------------------
def comparison_picture(rgb, pred, gt, path, zoom: int = 3, gap: int = 3) -> Path:
    """Rows of RGB | predicted depth (median-scaled) | GT depth, written as a PNG."""
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
    return write_image(path, img)


class LearningCurve:
    """Training callback: every ``every`` iterations, the held-out abs rel / delta < 1.25 /
    pose errors on 200 test frames, appended to ``curve.csv`` and plotted to ``curve.png``
    (training loss beside them). Rows of a resumed run are kept (read back from the CSV)."""

    COLUMNS = ("iteration", "loss", "photo", "abs_rel", "a1", "rot_err_deg", "trans_err_m")

    def __init__(self, folder: Path, test: Sequence, every: int):
        self.csv, self.png = Path(folder) / "curve.csv", Path(folder) / "curve.png"
        self.test = test.select_flights(np.unique(test.flight)[:4])  # 4 flights x 50 frames
        self.every = every
        self.rows = []
        if self.csv.is_file():
            lines = self.csv.read_text().splitlines()[1:]
            self.rows = [dict(zip(self.COLUMNS, map(float, line.split(",")))) for line in lines]

    def __call__(self, trainer, row) -> None:
        from ..viz import line_plot
        it = trainer.iteration
        if not self.every or (it % self.every and it != trainer.cfg.iterations):
            return
        if self.rows and self.rows[-1]["iteration"] >= it:
            return
        r = evaluate(DepthEstimator(trainer.disp), self.test, posenet=trainer.pose)
        self.rows.append({"iteration": it, "loss": row["loss"], "photo": row["photo"],
                          **{k: r[k] for k in self.COLUMNS[3:]}})
        text = ",".join(self.COLUMNS) + "\n" + "".join(
            ",".join(f"{rw[k]:.6g}" for k in self.COLUMNS) + "\n" for rw in self.rows)
        write_file(self.csv, text)
        its = [rw["iteration"] for rw in self.rows]
        line_plot({"held-out abs rel": (its, [rw["abs_rel"] for rw in self.rows]),
                   "held-out delta<1.25": (its, [rw["a1"] for rw in self.rows])},
                  self.png, title=f"{'/'.join(self.png.resolve().parts[-3:-1])}: held-out "
                                  f"depth quality (200 frames)",
                  xlabel="iteration", ylim=(0.0, 1.0))
