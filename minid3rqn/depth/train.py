"""The training loop: DispNet + PoseNet by view synthesis, with exact resumption.

One iteration:

    targets  <- B random triplet centres (rng seeded by ``seed``)
    disps    =  DispNet(I_t)                       multi-scale disparity
    poses    =  PoseNet(I_t, [I_t-1, I_t+1])       T_{t->s}, (B, 2, 6)
    loss     =  view_synthesis_loss(...)           losses.py
    Adam step on both networks

Every ``checkpoint_every`` iterations the networks, Adam's moments, the sampler's RNG
state and the log go into one ``.npz`` (written atomically); ``resume=True`` picks up
from it and continues exactly as if never stopped. A non-finite loss stops the run
with the iteration number.

At the end the metric scale is fixed without ground truth: the drone's forward speed
is known (2 m/s x 0.4 s = 0.8 m between frames), so

    scale = 0.8 / mean |t_pred|      over the training triplets

and depth = scale / disp is in metres (up to PoseNet's accuracy). ``DepthEstimator``
applies it.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .. import autograd as ag
from ..autograd.optim import Adam
from ..io import load_npz, save_npz
from ..nets.dispnet import DispNet
from ..nets.posenet import PoseNet
from ..world.geometry import relative_transform
from .data import FRAME_DT, SPEED, Sequence
from .cost_volume import plane_sweep_cost, sweep_depths
from .geometry import matrix_to_pose_vec
from .losses import LossConfig, view_synthesis_loss


@dataclass
class TrainConfig:
    iterations: int = 3000          # paper: 30000 at 128x416; scaled to our budget
    batch_size: int = 4             # paper
    lr: float = 5e-4                # paper: 5e-5; 10x trains faster here (docs/depth.md)
    lr_decay_at: int | None = None  # from this iteration on, lr x 0.1 (monodepth2-style step)
    seed: int = 0
    checkpoint_every: int = 250
    log_every: int = 25
    flip: bool = True               # random horizontal flips of whole triplets
    encoder: tuple = (16, 32, 64, 96)
    decoder: tuple = (16, 16, 32, 64)
    n_scales: int = 4
    init_disp: float | None = 0.5   # heads start at disp 0.5 (depth 2): log-middle of range
    pose_scale: float = 0.1         # SfMLearner: 0.01; our frames move 0.8 m and 0.2 rad
    pose_head_gain: float = 0.1
    pose_rot_scale: float | None = None      # rotation output scale (None: pose_scale)
    pose_dof: int = 6               # 6: SfMLearner; 3: planar (tx, tz, yaw)
    pose_init_forward: float | None = 0.8    # start PoseNet at tz = +-0.8 m (forward flight)
    gt_pose: bool = False           # ablation: warp with the GT relative poses, not PoseNet's
    gyro_noise: float = 0.005       # rad: std of the simulated gyro's yaw error per frame pair
    gyro_yaw: bool = False          # warp with the gyro's yaw in place of PoseNet's
    source_offsets: tuple = (-1, 1)  # the sources of target t: frames t + o (SfMLearner: -1, 1)
    prev_frame: bool = False        # ours: the DispNet also reads frame t - 1 (two frames in)
    cost_volume: int = 0            # ours: D > 0, it also reads a plane-sweep cost volume of
                                    # D depths against frame t - 1 (depth/cost_volume.py)
    loss: LossConfig = field(default_factory=LossConfig)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["encoder"], d["decoder"] = list(self.encoder), list(self.decoder)
        d["source_offsets"] = list(self.source_offsets)
        return d

    @staticmethod
    def from_dict(d: dict) -> "TrainConfig":
        d = dict(d)
        d["loss"] = LossConfig(**d.get("loss", {}))
        d["encoder"], d["decoder"] = tuple(d["encoder"]), tuple(d["decoder"])
        d["source_offsets"] = tuple(d.get("source_offsets", (-1, 1)))
        return TrainConfig(**d)


def build_nets(cfg: TrainConfig) -> tuple[DispNet, PoseNet]:
    rng = np.random.default_rng(cfg.seed)
    disp = DispNet(cfg.encoder, cfg.decoder, cfg.n_scales, init_disp=cfg.init_disp, rng=rng,
                   in_frames=2 if cfg.prev_frame else 1, cost_planes=cfg.cost_volume)
    # T_{t->s} of a source o frames later moves the camera o steps forward: its
    # translation starts at tz = -o x pose_init_forward (+0.8 m for the previous frame).
    pose = PoseNet(n_sources=len(cfg.source_offsets), pose_scale=cfg.pose_scale,
                   head_gain=cfg.pose_head_gain, dof=cfg.pose_dof, rng=rng,
                   rot_scale=cfg.pose_rot_scale,
                   init_tz=None if cfg.pose_init_forward is None else
                   tuple(-o * cfg.pose_init_forward for o in cfg.source_offsets))
    return disp, pose


def load_posenet(path) -> PoseNet:
    """The PoseNet of a training checkpoint (``Trainer.save_checkpoint``), built from the
    config stored beside it; for ``eval-depth --posenet``. A shipped model file holds
    the DispNet alone, so it is refused with a clear message."""
    arrays, meta = load_npz(path)
    weights = {k[len("pose."):]: v for k, v in arrays.items() if k.startswith("pose.")}
    if not weights or "config" not in (meta or {}):
        raise ValueError(f"load_posenet: {str(path)!r} holds no PoseNet; expected a training "
                         f"checkpoint (runs/depth/<run>/checkpoint.npz), not a model file")
    _, pose = build_nets(TrainConfig.from_dict(meta["config"]))
    pose.load_state_dict(weights)
    return pose


class Trainer:
    """Holds the networks, the optimizer and the sampler; ``run`` trains to the end."""

    def __init__(self, sequence: Sequence, cfg: TrainConfig, checkpoint=None,
                 resume: bool = False):
        if not isinstance(sequence, Sequence):
            raise TypeError(f"Trainer: sequence must be a data.Sequence; got "
                            f"{type(sequence).__name__}")
        self.seq, self.cfg = sequence, cfg
        if abs(cfg.loss.step - sequence.step) > 1e-6:
            raise ValueError(f"Trainer: the known-speed term expects {cfg.loss.step} m between "
                             f"frames (LossConfig.step) but the sequence moves "
                             f"{sequence.step} m (speed x dt in its metadata); set "
                             f"LossConfig.step to the sequence's step")
        self.offsets = tuple(cfg.source_offsets)
        if (cfg.prev_frame or cfg.cost_volume) and -1 not in self.offsets:
            raise ValueError(f"Trainer: prev_frame (a two-frame DispNet) and cost_volume read "
                             f"frame t - 1, so the source offsets must include -1; got "
                             f"{list(self.offsets)}")
        if cfg.cost_volume and sequence.pose is None:
            raise ValueError("Trainer: cost_volume needs the motion between frames (the "
                             "odometry); this sequence has no poses")
        self.targets = sequence.target_indices(self.offsets)
        if len(self.targets) == 0:
            raise ValueError(f"Trainer: the sequence has no triplet (a target with its sources "
                             f"at offsets {list(self.offsets)} in one flight); collect longer "
                             f"flights")
        h, w = sequence.shape
        if h % 2 ** (cfg.n_scales - 1) or w % 2 ** (cfg.n_scales - 1):
            raise ValueError(f"Trainer: image size {h}x{w} must be divisible by "
                             f"2^(n_scales - 1) = {2 ** (cfg.n_scales - 1)}")
        self.disp, self.pose = build_nets(cfg)
        self.params = self.disp.parameters() + self.pose.parameters()
        self.opt = Adam(self.params, lr=cfg.lr)
        self.rng = np.random.default_rng([cfg.seed, 1])
        self.iteration = 0
        self.history: list[dict] = []
        self.checkpoint = Path(checkpoint) if checkpoint else None
        if resume and self.checkpoint and self.checkpoint.is_file():
            self.load_checkpoint(self.checkpoint)

    # -- one step ------------------------------------------------------------------
    def sample_batch(self):
        idx = self.rng.choice(self.targets, size=self.cfg.batch_size, replace=True)
        target, sources = self.seq.batch(idx, self.offsets)
        K = self.seq.K
        if self.cfg.flip:
            flip = self.rng.random(self.cfg.batch_size) < 0.5
            # Mirroring a whole triplet is another valid flight (K is symmetric:
            # cx = (W - 1) / 2), seen in a mirrored world.
            target = np.where(flip[:, None, None, None], target[..., ::-1], target)
            sources = [np.where(flip[:, None, None, None], s[..., ::-1], s) for s in sources]
        self._last = (idx, flip if self.cfg.flip else np.zeros(len(idx), bool))
        return np.ascontiguousarray(target), [np.ascontiguousarray(s) for s in sources], K

    def gt_pose_vectors(self, idx, flip) -> np.ndarray:
        """The GT T_{t->s} of targets ``idx`` as (B, S, 6) pose vectors, mirrored where the
        triplet was flipped (M T M with M = diag(-1, 1, 1, 1)); for the GT-pose ablation
        and the gyro's yaw."""
        if self.seq.pose is None:
            raise ValueError("train-depth: gt_pose needs a sequence with GT poses")
        out = [matrix_to_pose_vec(self.motion(idx, offset, flip)) for offset in self.offsets]
        return np.stack(out, 1).astype(np.float32)

    def motion(self, idx, offset: int, flip) -> np.ndarray:
        """T_{t->t+offset} (B, 4, 4) of targets ``idx`` from the flights' poses, mirrored
        where the triplet was flipped (M T M with M = diag(-1, 1, 1, 1))."""
        M = np.diag([-1.0, 1.0, 1.0, 1.0])
        T = relative_transform(self.seq.pose[idx], self.seq.pose[idx + offset])
        return np.where(np.asarray(flip)[:, None, None], M @ T @ M, T)

    def gyro_yaws(self, idx, flip) -> np.ndarray:
        """The yaw between each target and its sources as a rate gyro reports it: the true
        yaw change (ry of T_{t->s}, mirrored with the image) plus Gaussian noise of
        ``gyro_noise`` rad. (B, S)."""
        yaw = self.gt_pose_vectors(idx, flip)[..., 4]
        return (yaw + self.rng.normal(0.0, self.cfg.gyro_noise, yaw.shape)).astype(np.float32)

    def current_lr(self) -> float:
        """The learning rate of the next step: lr, x 0.1 from ``lr_decay_at`` on."""
        decay = self.cfg.lr_decay_at is not None and self.iteration >= self.cfg.lr_decay_at
        return self.cfg.lr * (0.1 if decay else 1.0)

    def disp_input(self, target: np.ndarray, sources) -> np.ndarray:
        """What the DispNet reads: the target frames (B, 3, H, W), with ``prev_frame``
        the frames before them too (B, 6, H, W), and with ``cost_volume`` = D the cost
        volume against the frames before them after that (B, 3 + D, H, W). The cost
        volume's motion is the flight's (mirrored with a mirrored triplet): the
        odometry a quadrotor has, as in the flights (``DepthEstimator.sequence_motion``)."""
        prev = sources[self.offsets.index(-1)] if self.offsets and -1 in self.offsets else None
        x = np.concatenate([target, prev], axis=1) if self.cfg.prev_frame else target
        if not self.cfg.cost_volume:
            return x
        idx, flip = self._last
        mirror = lambda rgb: np.where(flip[:, None, None, None], rgb[:, :, ::-1], rgb)
        cost = plane_sweep_cost(mirror(self.seq.rgb[idx]), mirror(self.seq.rgb[idx - 1]),
                                self.motion(idx, -1, flip), self.seq.K,
                                sweep_depths(self.cfg.cost_volume))
        return np.concatenate([x, cost.transpose(0, 3, 1, 2)], axis=1)

    def step(self) -> dict:
        target, sources, K = self.sample_batch()
        disps = self.disp(self.disp_input(target, sources))
        use_gyro = self.cfg.loss.gyro_weight > 0 or (self.cfg.gyro_yaw and not self.cfg.gt_pose)
        gyro = self.gyro_yaws(*self._last) if use_gyro else None
        if self.cfg.gt_pose:
            poses = ag.Tensor(self.gt_pose_vectors(*self._last))
        else:
            poses = self.pose(target, sources)
        if self.cfg.gyro_yaw and not self.cfg.gt_pose:
            # Visual-inertial: the rotation about the vertical axis comes from the gyro,
            # PoseNet supplies the translation and the (small) pitch and roll.
            keep = np.ones(6, np.float32)
            keep[4] = 0.0
            yaw = np.zeros(poses.shape, np.float32)
            yaw[..., 4] = gyro
            poses = poses * keep + yaw
        for name, t in [("disparity", d) for d in disps] + [("pose", poses)]:
            if not np.isfinite(t.data).all():
                raise FloatingPointError(
                    f"train-depth: the predicted {name} holds NaN/inf at iteration "
                    f"{self.iteration + 1}, so the loss would be NaN; try a smaller --lr")
        loss, info = view_synthesis_loss(target, sources, disps, poses, K, self.cfg.loss, gyro,
                                         source_steps=np.abs(self.offsets))
        value = float(loss.data)
        if not math.isfinite(value):
            raise FloatingPointError(
                f"train-depth: the loss became {value} at iteration {self.iteration + 1} "
                f"(photo {info['photo']}, smooth {info['smooth']}); try a smaller --lr")
        self.opt.zero_grad()
        loss.backward()
        self.opt.lr = self.current_lr()
        self.opt.step()
        self.iteration += 1
        info["loss"] = value
        return info

    def run(self, progress: bool = True, callback=None) -> list[dict]:
        cfg = self.cfg
        bar = None
        if progress:
            from tqdm import tqdm
            bar = tqdm(total=cfg.iterations, initial=self.iteration, desc="train-depth",
                       unit="it", dynamic_ncols=True)
        window, t0 = [], time.time()
        while self.iteration < cfg.iterations:
            info = self.step()
            window.append(info)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{info['loss']:.4f}", photo=f"{info['photo']:.4f}")
            if self.iteration % cfg.log_every == 0 or self.iteration == cfg.iterations:
                row = {k: float(np.mean([w[k] for w in window])) for k in window[0]}
                row["iteration"] = self.iteration
                row["seconds"] = time.time() - t0
                self.history.append(row)
                window = []
                if callback is not None:
                    callback(self, row)
            if self.checkpoint and (self.iteration % cfg.checkpoint_every == 0
                                    or self.iteration == cfg.iterations):
                self.save_checkpoint(self.checkpoint)
        if bar is not None:
            bar.close()
        return self.history

    # -- checkpoints -----------------------------------------------------------------
    def save_checkpoint(self, path) -> Path:
        arrays = {f"disp.{k}": v for k, v in self.disp.state_dict().items()}
        arrays.update({f"pose.{k}": v for k, v in self.pose.state_dict().items()})
        arrays.update({f"opt.{k}": v for k, v in self.opt.state_dict().items()})
        meta = {"iteration": self.iteration, "config": self.cfg.to_dict(),
                "rng": _jsonable(self.rng.bit_generator.state), "history": self.history,
                "horizon_row": float(self.seq.K[1, 2]),      # the camera of the frames
                "K": self.seq.K.tolist()}
        return save_npz(path, arrays, meta)

    def init_from(self, path) -> None:
        """Start from another run's weights (fine-tuning, e.g. for scenario transfer);
        the optimizer, the sampler and the iteration count start fresh.

        ``path`` is either a training checkpoint (DispNet + PoseNet) or a depth model file
        as shipped in ``minid3rqn/models`` (DispNet only: PoseNet then starts from its own
        initialisation, at the known forward motion)."""
        arrays, _ = load_npz(path)
        pick = lambda prefix: {k[len(prefix):]: v for k, v in arrays.items()
                               if k.startswith(prefix)}
        if any(k.startswith("disp.") for k in arrays):
            self.disp.load_state_dict(self._widened(pick("disp.")))
            self.pose.load_state_dict(pick("pose."))
        else:  # a DepthEstimator file: the DispNet's weights under their own names
            self.disp.load_state_dict(self._widened({k: v for k, v in arrays.items()
                                                     if "." in k}))

    def _widened(self, weights: dict) -> dict:
        """A one-frame DispNet's weights for this run's two-frame or cost-volume DispNet:
        the first conv's kernels of the new channels (the previous frame's, the cost
        planes) start at zero, so the network starts out computing exactly what the
        one-frame network did, and learns from there what they add. Other weights:
        unchanged."""
        first = weights.get("enc_a.0.weight")
        extra = self.disp.in_channels - 3
        if extra and first is not None and first.shape[1] == 3:
            weights = dict(weights)
            zeros = np.zeros(first.shape[:1] + (extra,) + first.shape[2:], first.dtype)
            weights["enc_a.0.weight"] = np.concatenate([first, zeros], axis=1)
        return weights

    def load_checkpoint(self, path) -> None:
        arrays, meta = load_npz(path)
        saved = TrainConfig.from_dict(meta["config"])
        for key in ("seed", "batch_size", "encoder", "decoder", "n_scales", "lr", "loss",
                    "init_disp", "pose_scale", "pose_head_gain", "pose_dof", "pose_init_forward",
                    "pose_rot_scale", "gt_pose", "gyro_yaw", "gyro_noise", "prev_frame",
                    "cost_volume"):
            if getattr(saved, key) != getattr(self.cfg, key):
                raise ValueError(f"resume: the checkpoint {str(path)!r} was made with {key} = "
                                 f"{getattr(saved, key)!r}, this run asks {getattr(self.cfg, key)!r}")
        pick = lambda prefix: {k[len(prefix):]: v for k, v in arrays.items()
                               if k.startswith(prefix)}
        self.disp.load_state_dict(pick("disp."))
        self.pose.load_state_dict(pick("pose."))
        self.opt.load_state_dict(pick("opt."))
        self.rng.bit_generator.state = meta["rng"]
        self.iteration = int(meta["iteration"])
        self.history = list(meta["history"])

    # -- the metric scale from the known flight speed ----------------------------------
    def speed_scale(self, max_triplets: int = 400) -> float:
        return speed_scale(self.pose, self.seq, max_triplets, step=self.seq.step,
                           offsets=self.offsets)


def speed_scale(posenet: PoseNet, seq: Sequence, max_triplets: int = 400,
                step: float = SPEED * FRAME_DT, offsets=(-1, 1)) -> float:
    """scale = step / mean (|t_pred| / |o|) over (up to ``max_triplets``) targets and all
    their sources (o frames away: o steps flown).

    ``step`` is the distance flown between frames (known from the drone's speed, not
    from ground truth). Multiplying the network's depth (1 / disp) by this scale gives
    metres.
    """
    idx = seq.target_indices(offsets)
    if len(idx) > max_triplets:
        idx = idx[np.linspace(0, len(idx) - 1, max_triplets).astype(int)]
    per_step = np.abs(np.asarray(offsets, dtype=np.float64))
    norms = []
    with ag.no_grad():
        for k in range(0, len(idx), 64):
            target, sources = seq.batch(idx[k:k + 64], offsets)
            poses = posenet(target, sources).data
            norms.append((np.linalg.norm(poses[..., :3], axis=-1) / per_step).ravel())
    mean = float(np.mean(np.concatenate(norms)))
    if not mean > 0:
        raise FloatingPointError("speed_scale: PoseNet predicts no motion at all")
    return step / mean


def _jsonable(obj):
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (np.integer,)):
        return int(obj)
    return obj


__all__ = ["TrainConfig", "Trainer", "build_nets", "load_posenet", "speed_scale"]
