"""Command-line hooks: ``collect``, ``train-depth``, ``eval-depth``.

    python -m minid3rqn collect --scenario basic --frames 5000 --seed 0
    python -m minid3rqn train-depth --scenario basic --seed 0
    python -m minid3rqn eval-depth --model minid3rqn/models/depth_basic.npz --scenario basic

Files, unless given: ``runs/depth/<scenario>/train.npz`` (seed s) and ``test.npz``
(held-out flights in other scenes, seed s + 1000), ``checkpoint.npz``, ``model.npz``,
``results.json`` and ``pictures.png`` in the same folder. ``train-depth`` collects the
frames it needs when the files are missing, so one command reproduces a result, and
``--scenario channel`` (or intersections, corners) is the scenario transfer: the same
command retrains the depth network on that scenario's frames.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from ..io import machine

RUNS = Path("runs/depth")
TEST_SEED_OFFSET = 1000


def _paths(args) -> dict:
    folder = Path(getattr(args, "dir", None) or RUNS / args.scenario)
    return {"dir": folder, "train": Path(getattr(args, "data", None) or folder / "train.npz"),
            "test": Path(getattr(args, "test_data", None) or folder / "test.npz"),
            "checkpoint": folder / "checkpoint.npz",
            "model": Path(getattr(args, "out", None) or folder / "model.npz")}


def _command_line(args, name: str) -> str:
    """The command that reproduces this run, every option spelled out."""
    parts = ["python -m minid3rqn", name]
    for key, value in vars(args).items():
        if key.startswith("_") or key == "command" or value is None or value is False:
            continue
        flag = "--" + key.replace("_", "-")
        if value is True:
            parts.append(flag)
        elif str(value).startswith("-"):     # "--source-offsets -1,1" would read -1,1 as a flag
            parts.append(f"{flag}={value}")
        else:
            parts.append(f"{flag} {value}")
    return " ".join(parts)


# -- collect -----------------------------------------------------------------------------
def add_arguments_collect(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="basic",
                   help="basic | channel | intersections | corners")
    p.add_argument("--frames", type=int, default=5000, help="frames to collect (paper: 5000)")
    p.add_argument("--frames-per-flight", type=int, default=50)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="output .npz (default runs/depth/<scenario>/"
                   "train.npz)")
    p.add_argument("--late-turns", type=float, default=0.0,
                   help="share of the pilot's segments flown straight at obstacles, "
                        "swerving late (0: the careful pilot)")
    p.add_argument("--frame-dt", type=float, default=0.4,
                   help="seconds between frames (paper: 0.4)")
    p.add_argument("--crab-deg", type=float, default=0.0,
                   help="largest crab angle (camera heading off the direction of flight), "
                        "drawn per flight; moves the focus of expansion off the image "
                        "centre (0: the camera looks where the drone flies)")
    add_argument_horizon_row(p)
    p.add_argument("--pilot", default=None,
                   help="fly a trained Q-net (.npz) instead of the scripted pilot (ours): "
                        "frames of the states the Q-net itself visits (rl/flown_frames.py)")
    p.add_argument("--pilot-epsilon", type=float, default=0.0,
                   help="--pilot: probability of a random action at each step")
    p.add_argument("--pilot-depth", default="pred", choices=["pred", "gt"],
                   help="--pilot: what the Q-net reads (pred: the DispNet's depth, as deployed)")
    p.add_argument("--pilot-depth-model", default=None,
                   help="--pilot: the DispNet it reads (default: the shipped one of the scenario)")


def add_argument_horizon_row(p: argparse.ArgumentParser,
                             default: str = "the middle row, 15.5 of 32") -> None:
    """``--horizon-row`` (Camera.horizon_row), the same in every command; ``default``
    says what the command uses when it is not given."""
    p.add_argument("--horizon-row", type=float, default=None,
                   help=f"image row of the horizon (default: {default}); a smaller value "
                        f"shows more floor: 4 sees the floor from 1.93 m ahead instead of "
                        f"3.35 m (docs/depth.md section 7)")


def camera_or_exit(command: str, horizon_row=None):
    """The world's camera with this horizon row, or a clear exit naming the option."""
    from ..world.camera import Camera
    try:
        return Camera(horizon_row=horizon_row)
    except ValueError as e:
        raise SystemExit(f"{command} --horizon-row: {e}")


def camera_from_args(args, command: str):
    """The world's camera with the command's ``--horizon-row``, or a clear exit."""
    return camera_or_exit(command, getattr(args, "horizon_row", None))


def run_collect(args) -> int:
    from .data import collect, save_sequence
    out = Path(args.out or RUNS / args.scenario / "train.npz")
    t0 = time.time()
    if args.pilot:
        return _run_collect_flown(args, out, t0)
    data = collect(args.scenario, args.frames, args.frames_per_flight, args.seed,
                   camera=camera_from_args(args, "collect"),
                   late=args.late_turns, frame_dt=args.frame_dt, crab_deg=args.crab_deg)
    save_sequence(out, data, {"scenario": args.scenario, "seed": args.seed,
                              "late_turns": args.late_turns,
                              "command": _command_line(args, "collect")})
    print(f"collect: {len(data['rgb'])} frames in {int(data['flight'].max()) + 1} flights "
          f"-> {out} ({time.time() - t0:.1f} s)")
    return 0


def _run_collect_flown(args, out: Path, t0: float) -> int:
    """``collect --pilot QNET``: the frames of a Q-net's own flights."""
    from ..rl.commands import _estimator_for, horizon_for
    from ..rl.flown_frames import collect_flown
    from ..rl.policies import QNetPolicy
    from .data import save_sequence
    for name, value, default in (("--late-turns", args.late_turns, 0.0),
                                 ("--frame-dt", args.frame_dt, 0.4),
                                 ("--crab-deg", args.crab_deg, 0.0)):
        if value != default:
            raise SystemExit(f"collect: {name} is the scripted pilot's; with --pilot the "
                             f"Q-net flies (one frame per action, 0.4 s); got {name} {value}")
    if not 0.0 <= args.pilot_epsilon <= 1.0:
        raise SystemExit(f"collect --pilot-epsilon: expected a probability in [0, 1]; "
                         f"got {args.pilot_epsilon}")
    if args.frames_per_flight < 3:
        raise SystemExit(f"collect --frames-per-flight: expected >= 3; got "
                         f"{args.frames_per_flight}")
    if not Path(args.pilot).is_file():
        raise SystemExit(f"collect --pilot: no Q-net file {args.pilot!r}")
    policy = QNetPolicy.load(args.pilot, "pilot")
    policy.epsilon = args.pilot_epsilon
    est = _estimator_for(args.pilot_depth, args.pilot_depth_model, args.scenario)
    horizon = horizon_for("collect", args.horizon_row, est, [policy])
    camera = camera_or_exit("collect", horizon)
    data = collect_flown(policy, args.scenario, args.frames, args.seed, depth=args.pilot_depth,
                         depth_estimator=est, camera=camera,
                         max_steps=args.frames_per_flight - 1)
    save_sequence(out, data, {"scenario": args.scenario, "seed": args.seed,
                              "pilot": str(args.pilot), "pilot_epsilon": args.pilot_epsilon,
                              "pilot_depth": args.pilot_depth,
                              "command": _command_line(args, "collect")})
    print(f"collect: {len(data['rgb'])} frames in {int(data['flight'].max()) + 1} flights "
          f"of {args.pilot} -> {out} ({time.time() - t0:.1f} s)")
    return 0


def _picture_rows(estimator, test, n: int = 6) -> np.ndarray:
    """``n`` frames spread over ``test`` that the estimator can predict (for a two-frame
    model: frames with a previous frame in their flight)."""
    idx = estimator.sequence_targets(test)
    return idx[np.linspace(0, len(idx) - 1, n).astype(int)]


def _ensure_data(path: Path, scenario: str, frames: int, seed: int, fpf: int = 50,
                 late: float = 0.0, frame_dt: float = 0.4, crab_deg: float = 0.0,
                 camera=None):
    from ..world.camera import Camera
    from .data import FRAME_DT, collect, load_sequence, save_sequence
    camera = camera or Camera()
    if not path.is_file():
        data = collect(scenario, frames, fpf, seed, camera=camera, late=late,
                       frame_dt=frame_dt, crab_deg=crab_deg)
        extra = (f" --late-turns {late}" if late else "") + \
            (f" --frame-dt {frame_dt}" if frame_dt != FRAME_DT else "") + \
            (f" --crab-deg {crab_deg}" if crab_deg else "") + \
            (f" --horizon-row {camera.horizon_row:g}" if camera.horizon_row is not None
             else "")
        save_sequence(path, data, {"scenario": scenario, "seed": seed, "late_turns": late,
                                   "command": f"python -m minid3rqn collect --scenario "
                                              f"{scenario} --frames {frames} --seed {seed} "
                                              f"--out {path}{extra}"})
    seq = load_sequence(path)
    if abs(float(seq.K[1, 2]) - camera.cy) > 1e-6:
        raise SystemExit(f"{path}: its frames were filmed with the horizon at row "
                         f"{float(seq.K[1, 2]):g}, but this command's camera has it at row "
                         f"{camera.cy:g} (--horizon-row); give another --dir or --data")
    return seq


# -- train-depth ---------------------------------------------------------------------------
def add_arguments_train_depth(p: argparse.ArgumentParser) -> None:
    from .train import TrainConfig
    d = TrainConfig()
    p.add_argument("--scenario", default="basic")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--frames", type=int, default=5000, help="training frames to collect")
    p.add_argument("--test-frames", type=int, default=500, help="held-out frames to collect")
    p.add_argument("--late-turns", type=float, default=0.0,
                   help="training frames: share of the pilot's segments flown straight at "
                        "obstacles, swerving late (collect --late-turns); held-out frames "
                        "always come from the careful pilot")
    p.add_argument("--frame-dt", type=float, default=0.4,
                   help="training frames: seconds between frames (collect --frame-dt; paper "
                        "0.4); held-out frames always 0.4 s")
    p.add_argument("--crab-deg", type=float, default=0.0,
                   help="training frames: largest crab angle (collect --crab-deg); held-out "
                        "frames always look where the drone flies")
    add_argument_horizon_row(p)
    p.add_argument("--iterations", type=int, default=d.iterations)
    p.add_argument("--batch-size", type=int, default=d.batch_size)
    p.add_argument("--lr", type=float, default=d.lr)
    p.add_argument("--lr-decay-at", type=int, default=d.lr_decay_at,
                   help="from this iteration on, lr x 0.1 (default: never)")
    p.add_argument("--eval-every", type=int, default=500,
                   help="held-out evaluation (200 frames) every N iterations, for the "
                        "learning curve curve.csv/.png (0: off)")
    p.add_argument("--gyro-weight", type=float, default=d.loss.gyro_weight,
                   help="weight of the gyro term: PoseNet's yaw vs the drone's rate gyro "
                        "(0: images alone, as SfMLearner)")
    p.add_argument("--gyro-yaw", action="store_true",
                   help="warp with the (simulated, noisy) gyro's yaw in place of PoseNet's")
    p.add_argument("--gt-pose", action="store_true",
                   help="ablation: warp with GT relative poses instead of PoseNet's")
    p.add_argument("--ssim", type=float, default=d.loss.ssim_weight,
                   help="SSIM weight alpha (0: plain L1)")
    p.add_argument("--smooth", type=float, default=d.loss.smooth_weight)
    p.add_argument("--smooth-order", type=int, default=d.loss.smooth_order, choices=(1, 2),
                   help="1: penalise disparity slopes; 2: curvature (planes cost nothing)")
    p.add_argument("--speed-weight", type=float, default=d.loss.speed_weight,
                   help="weight of the known-speed term (0 disables it)")
    p.add_argument("--pose-dof", type=int, default=d.pose_dof, choices=(3, 6),
                   help="6: full pose; 3: planar (sideways, forward, yaw)")
    p.add_argument("--pose-init-forward", type=float, default=d.pose_init_forward,
                   help="PoseNet starts at this forward motion per frame (m); <= 0: at 0")
    p.add_argument("--init-disp", type=float, default=d.init_disp,
                   help="disparity the heads start at (1 / metres): 0.5 = 2 m, 0.1 = 10 m")
    p.add_argument("--pose-rot-scale", type=float, default=d.pose_rot_scale,
                   help="PoseNet rotation output scale (default: the translation's, 0.1)")
    p.add_argument("--unmasked-weight", type=float, default=d.loss.unmasked_weight,
                   help="weight of an unmasked photometric term beside the auto-mask")
    p.add_argument("--source-offsets", default="-1,1",
                   help="frames the target is synthesised from, as offsets from it: -1,1 "
                        "(previous and next: SfMLearner) or e.g. -2,-1,1,2 (two baselines; "
                        "the per-pixel minimum picks the one that explains each pixel)")
    p.add_argument("--full-res", action="store_true",
                   help="monodepth2's loss: upsample every scale's disparity and warp the "
                        "full-size images (default: SfMLearner's downsampled images)")
    p.add_argument("--prev-frame", action="store_true",
                   help="ours: a two-frame DispNet, which also reads the frame before (the "
                        "motion between them); --init-from a one-frame model starts it "
                        "where that model is (docs/depth.md section 7)")
    p.add_argument("--cost-volume", type=int, default=0, metavar="D",
                   help="ours: the DispNet also reads a plane-sweep cost volume of D depths "
                        "built from the frame before and the known motion (depth/"
                        "cost_volume.py); --init-from a model without one starts it where "
                        "that model is. 0 (default): none")
    p.add_argument("--no-edge-aware", action="store_true")
    p.add_argument("--no-min-reprojection", action="store_true")
    p.add_argument("--no-automask", action="store_true")
    p.add_argument("--no-flip", action="store_true")
    p.add_argument("--checkpoint-every", type=int, default=d.checkpoint_every)
    p.add_argument("--resume", action="store_true",
                   help="continue from the folder's checkpoint.npz if present")
    p.add_argument("--init-from", default=None,
                   help="fine-tune: start from this checkpoint's DispNet + PoseNet weights "
                        "(e.g. runs/depth/basic/checkpoint.npz)")
    p.add_argument("--dir", default=None, help="run folder (default runs/depth/<scenario>)")
    p.add_argument("--data", default=None, help="training .npz (collected if missing)")
    p.add_argument("--test-data", default=None, help="held-out .npz (collected if missing)")
    p.add_argument("--out", default=None, help="model file (default <dir>/model.npz)")
    p.add_argument("--ship", action="store_true",
                   help="also copy the model to minid3rqn/models/depth_<scenario>.npz/.json")
    p.add_argument("--smoke", action="store_true", help="tiny run (seconds), for tests")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _offsets(text: str) -> tuple[int, ...]:
    try:
        offsets = tuple(int(v) for v in str(text).split(","))
    except ValueError:
        raise ValueError(f"train-depth: --source-offsets must be comma-separated integers "
                         f"such as -1,1; got {text!r}") from None
    from .data import check_source_offsets
    return check_source_offsets(offsets)


def config_from_args(args):
    from .losses import LossConfig
    from .train import TrainConfig
    loss = LossConfig(ssim_weight=args.ssim, smooth_weight=args.smooth,
                      smooth_order=args.smooth_order, gyro_weight=args.gyro_weight,
                      edge_aware=not args.no_edge_aware,
                      min_reprojection=not args.no_min_reprojection,
                      automask=not args.no_automask, speed_weight=args.speed_weight,
                      unmasked_weight=args.unmasked_weight, full_res=args.full_res)
    init = args.pose_init_forward if args.pose_init_forward and args.pose_init_forward > 0 \
        else None
    return TrainConfig(iterations=args.iterations, batch_size=args.batch_size, lr=args.lr,
                       lr_decay_at=args.lr_decay_at, gt_pose=args.gt_pose,
                       gyro_yaw=args.gyro_yaw,
                       seed=args.seed, checkpoint_every=args.checkpoint_every,
                       flip=not args.no_flip, pose_dof=args.pose_dof,
                       init_disp=args.init_disp, pose_rot_scale=args.pose_rot_scale,
                       pose_init_forward=init, loss=loss,
                       source_offsets=_offsets(args.source_offsets),
                       prev_frame=args.prev_frame, cost_volume=args.cost_volume)


class _LearningCurve:
    """Training callback: every ``every`` iterations, the held-out abs rel / delta < 1.25 /
    pose errors on 200 test frames, appended to ``curve.csv`` and plotted to ``curve.png``
    (training loss beside them). Rows of a resumed run are kept (read back from the CSV)."""

    COLUMNS = ("iteration", "loss", "photo", "abs_rel", "a1", "rot_err_deg", "trans_err_m")

    def __init__(self, folder: Path, test, every: int):
        self.csv, self.png = folder / "curve.csv", folder / "curve.png"
        self.test = test.select_flights(np.unique(test.flight)[:4])  # 4 flights x 50 frames
        self.every = every
        self.rows = []
        if self.csv.is_file():
            lines = self.csv.read_text().splitlines()[1:]
            self.rows = [dict(zip(self.COLUMNS, map(float, line.split(",")))) for line in lines]

    def __call__(self, trainer, row) -> None:
        from ..viz import line_plot
        from .evaluate import DepthEstimator, evaluate
        it = trainer.iteration
        if not self.every or (it % self.every and it != trainer.cfg.iterations):
            return
        if self.rows and self.rows[-1]["iteration"] >= it:
            return
        est = DepthEstimator(trainer.disp, meta={"K": trainer.seq.K.tolist()})
        r = evaluate(est, self.test, posenet=trainer.pose)
        self.rows.append({"iteration": it, "loss": row["loss"], "photo": row["photo"],
                          **{k: r[k] for k in self.COLUMNS[3:]}})
        text = ",".join(self.COLUMNS) + "\n" + "".join(
            ",".join(f"{rw[k]:.6g}" for k in self.COLUMNS) + "\n" for rw in self.rows)
        tmp = self.csv.with_suffix(".csv.tmp")
        tmp.write_text(text)
        tmp.replace(self.csv)
        its = [rw["iteration"] for rw in self.rows]
        line_plot({"held-out abs rel": (its, [rw["abs_rel"] for rw in self.rows]),
                   "held-out delta<1.25": (its, [rw["a1"] for rw in self.rows])},
                  self.png, title="train-depth: held-out depth quality (200 frames)",
                  xlabel="iteration", ylim=(0.0, 1.0))


def run_train_depth(args) -> int:
    from .evaluate import DepthEstimator, comparison_picture, evaluate
    from .train import Trainer
    if args.smoke:
        args.frames, args.test_frames = min(args.frames, 60), min(args.test_frames, 30)
        args.iterations = min(args.iterations, 3)
        args.dir = args.dir or str(RUNS / f"smoke_{args.scenario}")
    paths = _paths(args)
    paths["dir"].mkdir(parents=True, exist_ok=True)
    cfg = config_from_args(args)
    t0 = time.time()
    camera = camera_from_args(args, "train-depth")
    train = _ensure_data(paths["train"], args.scenario, args.frames, args.seed,
                         late=args.late_turns, frame_dt=args.frame_dt, crab_deg=args.crab_deg,
                         camera=camera)
    test = _ensure_data(paths["test"], args.scenario, args.test_frames,
                        args.seed + TEST_SEED_OFFSET, camera=camera)
    t_data = time.time() - t0
    if abs(train.step - cfg.loss.step) > 1e-6:
        # Frames filmed closer together (collect --frame-dt): the known-speed term and
        # PoseNet's starting forward motion follow the data's step.
        if cfg.pose_init_forward == cfg.loss.step:
            cfg.pose_init_forward = train.step
        cfg.loss.step = train.step
    trainer = Trainer(train, cfg, checkpoint=paths["checkpoint"], resume=args.resume)
    if trainer.iteration:
        print(f"train-depth: resuming at iteration {trainer.iteration}")
    elif args.init_from:
        trainer.init_from(args.init_from)
    t1 = time.time()
    curve = _LearningCurve(paths["dir"], test, args.eval_every)
    trainer.run(progress=not args.quiet, callback=curve)
    t_train = time.time() - t1
    estimator = DepthEstimator(trainer.disp, trainer.speed_scale(), {"K": train.K.tolist()})
    results = evaluate(estimator, test, posenet=trainer.pose)
    meta = {"command": _command_line(args, "train-depth"), "seed": args.seed, "scenario": args.scenario,
            "horizon_row": camera.cy, "K": train.K.tolist(),
            "config": cfg.to_dict(), "results": results,
            "train_frames": len(train), "test_frames": len(test),
            "train_seconds": round(t_train, 1), "data_seconds": round(t_data, 1),
            "machine": machine(),
            "history": trainer.history[-1:] if trainer.history else []}
    estimator.save(paths["model"], meta)
    (paths["dir"] / "results.json").write_text(json.dumps(meta, indent=2))
    rows = _picture_rows(estimator, test)
    comparison_picture(test.rgb[rows], estimator.predict_sequence(test, rows), test.depth[rows],
                       paths["dir"] / "pictures.png")
    if args.ship:
        models = Path(__file__).resolve().parent.parent / "models"
        models.mkdir(exist_ok=True)
        shutil.copyfile(paths["model"], models / f"depth_{args.scenario}.npz")
        (models / f"depth_{args.scenario}.json").write_text(json.dumps(
            {k: v for k, v in meta.items() if k != "history"}, indent=2))
    print(json.dumps({"scenario": args.scenario, "seed": args.seed,
                      "train_seconds": round(t_train, 1),
                      **{k: round(v, 4) for k, v in results.items()}}))
    return 0


# -- eval-depth ------------------------------------------------------------------------------
def add_arguments_eval_depth(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", default="minid3rqn/models/depth_basic.npz")
    p.add_argument("--scenario", default="basic")
    p.add_argument("--seed", type=int, default=0,
                   help="the training seed: held-out frames use seed + 1000")
    p.add_argument("--test-frames", type=int, default=500)
    p.add_argument("--test-data", default=None)
    p.add_argument("--with-previous", action="store_true",
                   help="score only the frames with a previous frame in their flight (all a "
                        "two-frame model can score), so that one- and two-frame models meet "
                        "on the same frames")
    p.add_argument("--flip-tta", action="store_true",
                   help="average the disparity with its value on the mirrored frame, "
                        "mirrored back (test-time flip; docs/depth.md section 7)")
    p.add_argument("--pictures", default=None, help="PNG: RGB | predicted | GT rows")
    p.add_argument("--json", default=None, help="write the metrics here")
    p.add_argument("--by-depth", action="store_true",
                   help="also print the errors per GT-depth bin (where the errors are)")
    p.add_argument("--metric-scale", action="store_true",
                   help="with --by-depth: judge the model's own metric scale (from the "
                        "flight speed) instead of per-image median scaling")
    p.add_argument("--columns", default="all", choices=["all", "centre", "sides"],
                   help="with --by-depth: only the middle half of the image width (what "
                        "lies ahead) or the outer quarters")
    p.add_argument("--posenet", default=None,
                   help="a training checkpoint (runs/depth/<run>/checkpoint.npz): also report "
                        "its PoseNet's pose errors on these frames")
    add_argument_horizon_row(p)
    p.add_argument("--band", default=None, metavar="ABOVE:BELOW",
                   help="score only the rows from ABOVE rows above the horizon to BELOW "
                        "rows below it (4:15.5: the band that the default camera and one "
                        "with --horizon-row 4 both see)")


def _band(text: str):
    try:
        above, below = (float(x) for x in text.split(":"))
    except ValueError:
        raise SystemExit(f"eval-depth --band: expected ABOVE:BELOW, two numbers of rows "
                         f"(e.g. 4:15.5); got {text!r}")
    return above, below


def run_eval_depth(args) -> int:
    from ..world.camera import Camera
    from .evaluate import DepthEstimator, comparison_picture, evaluate
    estimator = DepthEstimator.load(args.model, flip=args.flip_tta)
    path = Path(args.test_data or RUNS / args.scenario / "test.npz")
    test = _ensure_data(path, args.scenario, args.test_frames, args.seed + TEST_SEED_OFFSET,
                        camera=camera_from_args(args, "eval-depth")
                        if args.horizon_row is not None else
                        Camera(horizon_row=estimator.horizon_row))
    posenet = None
    if args.posenet:
        from .train import load_posenet
        posenet = load_posenet(args.posenet)
    band = None
    if args.band:
        from .evaluate import horizon_band
        try:
            band = horizon_band(test.K, test.rgb.shape[1], *_band(args.band))
        except ValueError as e:
            raise SystemExit(f"eval-depth --band: {e}")
    t0 = time.time()
    results = evaluate(estimator, test, posenet, rows=band, with_previous=args.with_previous)
    results["seconds"] = round(time.time() - t0, 2)
    if band is not None:
        results["band_rows"] = [int(np.flatnonzero(band)[0]), int(np.flatnonzero(band)[-1])]
    if args.by_depth:
        from .evaluate import errors_by_depth
        idx = estimator.sequence_targets(test, with_previous=args.with_previous)
        pred, gt = estimator.predict_sequence(test, idx), test.depth[idx]
        if band is not None:
            pred, gt = pred[:, band], gt[:, band]
        rows = errors_by_depth(pred, gt,
                               median_scaling=not args.metric_scale, columns=args.columns)
        print("GT depth (m)   share   abs rel   signed rel (> 0: too far)   "
              + ("[the model's metric scale]" if args.metric_scale else "[median-scaled]")
              + ("" if args.columns == "all" else f"  [{args.columns} columns]"))
        for r in rows:
            print(f"{r['from_m']:4.0f} - {r['to_m']:<4.0f}    {r['share']:.2f}    "
                  f"{r['abs_rel']:.3f}     {r['signed_rel']:+.3f}")
        results["by_depth"] = rows
    if args.pictures:
        rows = _picture_rows(estimator, test)
        comparison_picture(test.rgb[rows], estimator.predict_sequence(test, rows),
                           test.depth[rows], args.pictures)
    text = json.dumps({k: (round(v, 4) if isinstance(v, float) else v)
                       for k, v in results.items()})
    if args.json:
        Path(args.json).write_text(text)
    print(text)
    return 0


def main(argv=None) -> int:
    """``python -m minid3rqn.depth.commands <collect|train-depth|eval-depth> ...``."""
    parser = argparse.ArgumentParser(prog="python -m minid3rqn.depth.commands")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in ("collect", "train-depth", "eval-depth"):
        sp = sub.add_parser(name)
        globals()[f"add_arguments_{name.replace('-', '_')}"](sp)
    args = parser.parse_args(argv)
    return globals()[f"run_{args.command.replace('-', '_')}"](args)


if __name__ == "__main__":
    sys.exit(main())
