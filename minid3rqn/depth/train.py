"""The training loop: DispNet + PoseNet by view synthesis, with exact resumption.

One iteration (the paper's training, as SfMLearner trains):

    targets  <- B random triplet centres (rng seeded by ``seed``); each triplet is
                mirrored left-right with probability 1/2 (a mirrored flight is a flight
                in a mirrored world: SfMLearner's and monodepth2's augmentation)
    disps    =  DispNet(I_t)                       multi-scale disparity
    poses    =  PoseNet(I_t, [I_t-1, I_t+1])       T_{t->s}, (B, 2, 6)
    loss     =  view_synthesis_loss(...)           losses.py
    Adam step on both networks

``gyro_yaw`` (ours): the yaw of T_{t->s} comes from the drone's rate gyro (simulated:
the true yaw change plus noise) instead of PoseNet; PoseNet still gives the
translation and the small pitch and roll.

Every ``checkpoint_every`` iterations the networks, Adam's moments, the sampler's RNG
state and the log go into one ``.npz`` (written atomically); ``resume=True`` picks up
from it and continues exactly as if never stopped. A non-finite loss stops the run
with the iteration number.

At the end the metric scale is fixed without ground truth: the drone's forward speed
is known (2 m/s x 0.4 s = 0.8 m between frames), so

    scale = 0.8 / mean |t_pred|      over the training triplets

and depth = scale / disp is in metres (up to PoseNet's accuracy). ``DepthEstimator``
applies it. ``train_depth`` is a whole run: the frames, the training, the held-out
evaluation and the model file.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .. import autograd as ag
from ..autograd.optim import Adam
from ..config import (as_dict, at_least, changed_settings, command_line, fits_memory,
                      flat_settings, positive, setting, shell_command, validate)
from ..io import (RunStopped, StopRequest, WriteError, check_checkpoint_weights, load_npz,
                  machine, read_metadata, reading_checkpoint, save_npz, whole, write_json)
from ..nets.dispnet import DispNet
from ..nets.posenet import PoseNet
from ..world.geometry import relative_transform
from .data import (FRAME_BYTES, CollectConfig, Sequence, collect_sequence, held_out,
                   load_sequence)
from .evaluate import DepthEstimator, LearningCurve, comparison_picture, evaluate
from .geometry import matrix_to_pose_vec
from .losses import STEP, LossConfig, view_synthesis_loss

OFFSETS = (-1, 1)        # the sources of target t: frames t - 1 and t + 1 (the paper's)
POSE_SCALE = 0.1         # PoseNet's output scale (SfMLearner: 0.01; our frames move 0.8 m)
POSE_HEAD_GAIN = 0.1     # PoseNet's head starts small: the first poses are near its bias
GYRO_NOISE = 0.005       # rad: std of the simulated gyro's yaw error per frame pair


@dataclass
class TrainConfig:
    """The settings of one depth training run (see the module docstring)."""
    iterations: int = setting(3000, "training iterations (paper: 30000 at 128x416)",
                              source="budget", check=at_least(1))
    batch_size: int = setting(4, "triplets per iteration", source="paper", cli="more",
                              check=at_least(1))
    lr: float = setting(5e-4, "Adam's learning rate (paper: 5e-5; 10x trains faster here)",
                        source="budget", check=positive)
    seed: int = setting(0, "weights, batches, flips, gyro noise (and the frames train-depth "
                           "collects)", source="run", check=at_least(0))
    lr_decay_at: int | None = setting(None, "from this iteration on, lr x 0.1 (none: never)",
                                      source="ours", check=at_least(1))
    init_disp: float = setting(0.1, "disparity the heads start at (1 / metres): 0.1 = 10 m, "
                                    "beyond the scenes' depth (every shipped DispNet)",
                               source="ours",
                               check=lambda v: None if 0.01 < v < 10.01 else
                               "a disparity in (0.01, 10.01), DispNet's range")
    gyro_yaw: bool = setting(False, "warp with the (simulated, noisy) rate gyro's yaw in "
                                    "place of PoseNet's", source="ours")
    checkpoint_every: int = setting(250, "iterations between checkpoints", source="run",
                                    cli="more", check=at_least(1))
    log_every: int = setting(25, "iterations per row of the training log", source="run",
                             cli="more", check=at_least(1))
    eval_every: int = setting(500, "held-out check (200 frames) every N iterations, for "
                                   "curve.csv (0: none)", source="run", cli="more",
                              check=at_least(0))
    test_frames: int = setting(500, "held-out frames collected for the run (other worlds: "
                                    "seed + 1000)", source="run", cli="more",
                               check=fits_memory(3, FRAME_BYTES, "frames"))
    loss: LossConfig = setting(default_factory=LossConfig, help="the loss (losses.py)")

    def __post_init__(self):
        validate(self)


def build_nets(cfg: TrainConfig) -> tuple[DispNet, PoseNet]:
    """A fresh DispNet and PoseNet (seed ``cfg.seed``); PoseNet starts at the known
    forward motion STEP (0.8 m) per frame: T_{t->t-1} at tz = +STEP, T_{t->t+1} at -STEP."""
    rng = np.random.default_rng(cfg.seed)
    disp = DispNet(init_disp=cfg.init_disp, rng=rng)
    pose = PoseNet(n_sources=len(OFFSETS), pose_scale=POSE_SCALE, head_gain=POSE_HEAD_GAIN,
                   rng=rng, init_tz=tuple(-o * STEP for o in OFFSETS))
    return disp, pose


class Trainer:
    """Holds the networks, the optimizer and the sampler; ``run`` trains to the end.

    ``photometric_error``: (pred, target) -> (N, 1, H, W), the per-pixel error of the
    loss (default: the configured SSIM + L1, ``losses.photometric_error``). ``settings``:
    what a resumed run must share with its checkpoint besides ``cfg``'s settings ({name:
    value}, e.g. the frames' file)."""

    def __init__(self, sequence: Sequence, cfg: TrainConfig, checkpoint=None,
                 resume: bool = False, photometric_error=None, settings: dict | None = None):
        if not isinstance(sequence, Sequence):
            raise TypeError(f"Trainer: sequence must be a data.Sequence; got "
                            f"{type(sequence).__name__}")
        self.seq, self.cfg, self.photometric_error = sequence, cfg, photometric_error
        self.targets = sequence.triplet_indices()
        if len(self.targets) == 0:
            raise ValueError("Trainer: the sequence has no triplet (three consecutive "
                             "frames of one flight); collect longer flights")
        self.disp, self.pose = build_nets(cfg)
        h, w = sequence.shape
        if h % 2 ** (self.disp.n_scales - 1) or w % 2 ** (self.disp.n_scales - 1):
            raise ValueError(f"Trainer: image size {h}x{w} must be divisible by "
                             f"2^(n_scales - 1) = {2 ** (self.disp.n_scales - 1)}")
        self.params = self.disp.parameters() + self.pose.parameters()
        self.opt = Adam(self.params, lr=cfg.lr)
        self.rng = np.random.default_rng([cfg.seed, 1])
        self.iteration = 0
        self.history: list[dict] = []
        self.checkpoint = Path(checkpoint) if checkpoint else None
        self.settings = {**flat_settings(as_dict(cfg)), **(settings or {})}
        if resume and self.checkpoint and self.checkpoint.is_file():
            self.load_checkpoint(self.checkpoint)

    # -- one step ------------------------------------------------------------------
    def sample_batch(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """B triplets (target (B, 3, H, W), [previous, next]), each mirrored left-right
        with probability 1/2 (K is symmetric, cx = (W - 1) / 2, so a mirrored triplet
        is a flight in a mirrored world). ``self._last``: (targets, mirrored)."""
        idx = self.rng.choice(self.targets, size=self.cfg.batch_size, replace=True)
        target, sources = self.seq.batch(idx)
        flip = self.rng.random(self.cfg.batch_size) < 0.5
        target = np.where(flip[:, None, None, None], target[..., ::-1], target)
        sources = [np.where(flip[:, None, None, None], s[..., ::-1], s) for s in sources]
        self._last = (idx, flip)
        return np.ascontiguousarray(target), [np.ascontiguousarray(s) for s in sources]

    def motion(self, idx, offset: int, flip) -> np.ndarray:
        """T_{t->t+offset} (B, 4, 4) of targets ``idx`` from the flights' poses, mirrored
        where the triplet was flipped (M T M with M = diag(-1, 1, 1, 1))."""
        M = np.diag([-1.0, 1.0, 1.0, 1.0])
        T = relative_transform(self.seq.pose[idx], self.seq.pose[idx + offset])
        return np.where(np.asarray(flip)[:, None, None], M @ T @ M, T)

    def gyro_yaws(self, idx, flip) -> np.ndarray:
        """The yaw between each target and its sources as a rate gyro reports it: the true
        yaw change (ry of T_{t->s}, mirrored with the image) plus Gaussian noise of
        ``GYRO_NOISE`` rad. (B, 2)."""
        if self.seq.pose is None:
            raise ValueError("Trainer: gyro_yaw needs a sequence with the flights' poses")
        yaw = np.stack([matrix_to_pose_vec(self.motion(idx, o, flip))[..., 4]
                        for o in OFFSETS], 1).astype(np.float32)
        return (yaw + self.rng.normal(0.0, GYRO_NOISE, yaw.shape)).astype(np.float32)

    def current_lr(self) -> float:
        """The learning rate of the next step: lr, x 0.1 from ``lr_decay_at`` on."""
        decay = self.cfg.lr_decay_at is not None and self.iteration >= self.cfg.lr_decay_at
        return self.cfg.lr * (0.1 if decay else 1.0)

    def step(self) -> dict:
        target, sources = self.sample_batch()
        disps = self.disp(target)
        poses = self.pose(target, sources)
        if self.cfg.gyro_yaw:    # ry (index 4) from the gyro, the rest from PoseNet
            keep = np.ones(6, np.float32)
            keep[4] = 0.0
            yaw = np.zeros(poses.shape, np.float32)
            yaw[..., 4] = self.gyro_yaws(*self._last)
            poses = poses * keep + yaw
        for name, t in [("disparity", d) for d in disps] + [("pose", poses)]:
            if not np.isfinite(t.data).all():
                raise FloatingPointError(
                    f"the predicted {name} holds NaN/inf at iteration "
                    f"{self.iteration + 1}, so the loss would be NaN; try a smaller lr")
        loss, info = view_synthesis_loss(target, sources, disps, poses, self.seq.K,
                                         self.cfg.loss, self.photometric_error)
        value = float(loss.data)
        if not math.isfinite(value):
            raise FloatingPointError(
                f"the loss became {value} at iteration {self.iteration + 1} "
                f"(photo {info['photo']}, smooth {info['smooth']}); try a smaller lr")
        self.opt.zero_grad()
        loss.backward()
        self.opt.lr = self.current_lr()
        self.opt.step()
        self.iteration += 1
        info["loss"] = value
        return info

    def run(self, progress: bool = True, callback=None) -> list[dict]:
        """Train to ``cfg.iterations``; ``callback(trainer, row)`` after each log row.
        Ctrl-C stops at the end of an iteration: the checkpoint is saved (if the trainer
        has one), then ``io.RunStopped`` is raised."""
        cfg = self.cfg
        bar = None
        if progress:
            from tqdm import tqdm
            bar = tqdm(total=cfg.iterations, initial=self.iteration, desc="train-depth",
                       unit="it", dynamic_ncols=True)
        window, t0 = [], time.time()
        with StopRequest() as stop:     # Ctrl-C: stop at the end of an iteration
            while self.iteration < cfg.iterations and not stop.requested:
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
            if stop.requested and self.checkpoint:
                self.save_checkpoint(self.checkpoint)
        if self.iteration < cfg.iterations:
            if not self.checkpoint:
                raise KeyboardInterrupt
            raise RunStopped(f"stopped at iteration {self.iteration} of {cfg.iterations}; "
                             f"the checkpoint is {str(self.checkpoint)!r}")
        return self.history

    # -- checkpoints -----------------------------------------------------------------
    def save_checkpoint(self, path) -> Path:
        arrays = {f"disp.{k}": v for k, v in self.disp.state_dict().items()}
        arrays.update({f"pose.{k}": v for k, v in self.pose.state_dict().items()})
        arrays.update({f"opt.{k}": v for k, v in self.opt.state_dict().items()})
        meta = {"iteration": self.iteration, "config": as_dict(self.cfg),
                "settings": self.settings,
                "rng": _jsonable(self.rng.bit_generator.state), "history": self.history}
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
            self.disp.load_state_dict(pick("disp."))
            self.pose.load_state_dict(pick("pose."))
        else:  # a DepthEstimator file: the DispNet's weights under their own names
            self.disp.load_state_dict({k: v for k, v in arrays.items() if "." in k})

    def load_checkpoint(self, path) -> None:
        """Continue from the checkpoint at ``path`` (``check_resume``: ValueError if it
        was made with other settings; ``DamagedCheckpoint`` if its contents do not fit)."""
        arrays, meta = load_npz(path)
        check_resume(meta, self.settings, path)
        pick = lambda prefix: {k[len(prefix):]: v for k, v in arrays.items()
                               if k.startswith(prefix)}
        with reading_checkpoint(path):
            check_checkpoint_weights(arrays)
            self.disp.load_state_dict(pick("disp."))
            self.pose.load_state_dict(pick("pose."))
            self.opt.load_state_dict(pick("opt."))
            self.rng.bit_generator.state = meta["rng"]
            self.iteration = int(meta["iteration"])
            self.history = list(meta["history"])

    # -- the metric scale from the known flight speed ----------------------------------
    def speed_scale(self, max_triplets: int = 400) -> float:
        return speed_scale(self.pose, self.seq, max_triplets)


# The settings a resumed run may change: how far it goes (iterations: train a run on),
# when the lr steps down, and how it reports; every other one must be its checkpoint's.
MAY_CHANGE_ON_RESUME = ("iterations", "lr_decay_at", "checkpoint_every", "log_every",
                        "eval_every")


def recorded_data(train_file, run_dir) -> str:
    """The training frames as a checkpoint records them: relative to the run folder when
    they lie in it (the default, ``train.npz``: the folder can be moved and resumed),
    else as a full path."""
    where, folder = Path(train_file).resolve(), Path(run_dir).resolve()
    return str(where.relative_to(folder)) if where.is_relative_to(folder) else str(where)


def check_resume(meta: dict, settings: dict, path) -> None:
    """ValueError unless a run of ``settings`` ({name: value}) may continue the checkpoint
    at ``path`` with metadata ``meta``: every setting the same but those of
    MAY_CHANGE_ON_RESUME, and no fewer iterations than it has done. The message names
    each differing setting with both values."""
    if not (isinstance(meta, dict) and isinstance(meta.get("iteration"), int)
            and isinstance(meta.get("config"), dict)):
        raise ValueError(f"resume: {str(path)!r} is not a train-depth checkpoint")
    if meta["iteration"] < 0:
        raise ValueError(f"resume: {str(path)!r} records an impossible iteration "
                         f"{meta['iteration']}; start afresh with --overwrite")
    saved = {**flat_settings(meta["config"]), **meta.get("settings", {})}
    data = saved.get("data")
    if isinstance(data, str) and Path(data).is_absolute() and \
            recorded_data(data, Path(path).parent) == settings.get("data"):
        saved["data"] = settings["data"]        # a full path, as older checkpoints record
    changed = changed_settings(saved, settings, MAY_CHANGE_ON_RESUME)
    if changed:
        raise ValueError(f"resume: the checkpoint {str(path)!r} was made with other "
                         f"settings: {'; '.join(changed)}; give the run's own (its "
                         f"results.json records its command), or start afresh")
    if meta["iteration"] > settings["iterations"]:
        raise ValueError(f"resume: the run of {str(path)!r} is at iteration "
                         f"{meta['iteration']} already, beyond iterations "
                         f"{settings['iterations']}; give at least {meta['iteration']}")


def speed_scale(posenet: PoseNet, seq: Sequence, max_triplets: int = 400) -> float:
    """scale = step / mean |t_pred| over (up to ``max_triplets``) triplets and both their
    sources, with step = STEP = speed x dt the distance flown between frames (known from
    the drone's speed, not from ground truth). Multiplying the network's depth (1 / disp)
    by this scale gives metres."""
    idx = seq.triplet_indices()
    if len(idx) > max_triplets:
        idx = idx[np.linspace(0, len(idx) - 1, max_triplets).astype(int)]
    norms = []
    with ag.no_grad():
        for k in range(0, len(idx), 64):
            target, sources = seq.batch(idx[k:k + 64])
            poses = posenet(target, sources).data
            norms.append(np.linalg.norm(poses[..., :3], axis=-1).astype(np.float64).ravel())
    mean = float(np.mean(np.concatenate(norms)))
    if not mean > 0:
        raise FloatingPointError("speed_scale: PoseNet predicts no motion at all")
    return STEP / mean


# -- a whole run ------------------------------------------------------------------------
def train_depth(cfg: TrainConfig, data: CollectConfig, run_dir, train_file=None,
                test_file=None, init_from=None, resume: bool = True,
                progress: bool = False) -> Path:
    """Train a DispNet + PoseNet in ``run_dir`` and write its model file; returns its path.

    The training frames are read from ``train_file`` (default ``run_dir/train.npz``),
    collected there with ``data`` when it does not exist; the held-out frames likewise
    from ``test_file`` (default ``run_dir/test.npz``), else ``cfg.test_frames`` frames
    of ``held_out(data)``. ``init_from``: a checkpoint or model file to fine-tune
    (ignored when a checkpoint is resumed, with ``resume``; a resumed run that has
    finished is left as it is). ``run_dir`` gets
    checkpoint.npz, curve.csv/.png (the held-out check every ``cfg.eval_every``
    iterations), model.npz, results.json (the model file's metadata: the configs, the
    ``train-depth`` and ``collect`` commands that reproduce it, the held-out results)
    and pictures.png (RGB | predicted | GT of six held-out frames).
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    train_path = Path(train_file or run_dir / "train.npz")
    train = _frames(train_path, data, progress, own=train_file is None)
    test = _frames(Path(test_file or run_dir / "test.npz"), held_out(data, cfg.test_frames),
                   progress, own=test_file is None)
    t_data = time.time() - t0
    trainer = Trainer(train, cfg, checkpoint=run_dir / "checkpoint.npz", resume=resume,
                      settings={"data": recorded_data(train_path, run_dir)})
    done = [run_dir / "model.npz", run_dir / "results.json", run_dir / "pictures.png"]
    if trainer.iteration >= cfg.iterations:
        if all(whole(p) for p in done):
            return done[0]               # a finished run: its model and results stand
        damaged = ", ".join(p.name for p in done if not whole(p))
        print(f"train-depth: the run has finished, but {damaged} is missing or damaged; "
              f"writing it again")
    if trainer.iteration:
        print(f"train-depth: resuming at iteration {trainer.iteration}")
    elif init_from:
        trainer.init_from(init_from)
    t1 = time.time()
    trainer.run(progress=progress, callback=LearningCurve(run_dir, test, cfg.eval_every))
    t_train = time.time() - t1
    estimator = DepthEstimator(trainer.disp, trainer.speed_scale())
    results = evaluate(estimator, test, posenet=trainer.pose)
    meta = {"command": train_depth_command(cfg, data, run_dir, train_file, test_file,
                                           init_from),
            "data_command": (train.meta or {}).get("command"),
            "seed": cfg.seed, "scenario": data.scenario, "config": as_dict(cfg),
            "data": as_dict(data), "results": results,
            "train_frames": len(train), "test_frames": len(test),
            "train_seconds": round(t_train, 1), "data_seconds": round(t_data, 1),
            "machine": machine(), "history": trainer.history[-1:]}
    try:
        model = estimator.save(run_dir / "model.npz", meta)
        write_json(run_dir / "results.json", meta)
        rows = np.linspace(0, len(test) - 1, 6).astype(int)
        comparison_picture(test.rgb[rows], estimator.predict(test.rgb[rows]),
                           test.depth[rows], run_dir / "pictures.png")
    except WriteError as e:             # the run is measured: the command says so
        e.measured = meta
        raise
    return model


def train_depth_command(cfg: TrainConfig, data: CollectConfig, run_dir, train_file=None,
                        test_file=None, init_from=None) -> str:
    """The ``train-depth`` command line of a ``train_depth`` run (its frames' seed is the
    run's; frames made otherwise come from ``train_file``, whose ``collect`` command the
    model file records beside it)."""
    shown = replace(CollectConfig(), scenario=data.scenario, frames=data.frames,
                    late_turns=data.late_turns)
    parts = ["train-depth", *command_line(CollectConfig, shown),
             *command_line(TrainConfig, cfg), "--dir", str(run_dir)]
    for flag, value in (("--data", train_file), ("--test-data", test_file),
                        ("--init-from", init_from)):
        if value is not None:
            parts += [flag, str(value)]
    return shell_command(parts)


def _frames(path: Path, data: CollectConfig, progress: bool, own: bool = False) -> Sequence:
    """The sequence file at ``path``, collected there with ``data`` if it is missing.
    ``own``: the run's own file (not given by the user), which must hold the frames of
    ``data`` (ValueError naming the differing settings otherwise)."""
    if not path.is_file():
        return collect_sequence(data, path, progress)
    problem = other_frames(path, data) if own else None
    if problem:
        raise ValueError(problem)
    return load_sequence(path)


def other_frames(path, data: CollectConfig) -> str | None:
    """Why the sequence file at ``path`` does not hold the frames ``data`` collects (its
    recorded settings differ: each named with both values), or None."""
    saved = read_metadata(path) or {}
    changed = changed_settings(saved, as_dict(data))
    if changed:
        return (f"{str(path)!r} holds frames collected with other settings: "
                f"{'; '.join(changed)}")
    return None


def _jsonable(obj):
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (np.integer,)):
        return int(obj)
    return obj
