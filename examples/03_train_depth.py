# %% [markdown]
# # 03: Depth from raw frames alone: why view synthesis works, then watch DispNet learn it
#
# 0. Why it works (``warp.png``, three rows, each target | second image | |difference|):
#    the previous frame warped into the target with the TRUE depth and motion
#    (p_s ~ K T_{t->s} D_t(p_t) K^-1 p_t, the paper's Eq. 3) matches it, except where the
#    source did not see the target's pixels; unwarped it does not (the camera moved);
#    warped with the depth halved it does not either. The only depth that makes the
#    first error small is the right one: that is what trains DispNet.
# 1. A scripted pilot flies the basic world; every 0.4 s the camera keeps a frame (the
#    ground-truth depth is stored beside it, for the scorecard only).
# 2. DispNet + PoseNet train on triplets (previous, target, next): warp the neighbours
#    into the target with the predicted depth and motion, compare the pixels.
# 3. Before training and every few hundred iterations the example scores the depth against
#    ground truth (abs rel, delta < 1.25) and adds a row RGB | predicted | GT to
#    ``emerging.png``. The heads start every pixel at 10 m (depth.md, section 5). Most of
#    the gain comes in the first 200 iterations (abs rel about 0.89 -> 0.55, delta
#    0.21 -> 0.35, seed 0): the noise becomes an even depth with the near floor under
#    it. After that, at this budget, the scores move back and forth by a little (abs rel
#    0.50, delta 0.36 at 800 iterations), and the wall on the left shows from about 600
#    iterations.
#
#     python examples/03_train_depth.py [--out runs/examples/03_train_depth]
#     python examples/03_train_depth.py --smoke    # seconds: tiny run, checks it works

# %%
"""Depth from raw frames alone: why view synthesis works, then watch DispNet learn it."""
import argparse
import sys
from pathlib import Path

import numpy as np

from minid3rqn import viz
from minid3rqn.depth.data import Sequence, collect
from minid3rqn.depth.evaluate import DepthEstimator, comparison_picture, evaluate
from minid3rqn.depth.train import TrainConfig, Trainer
from minid3rqn.io import write_image
from minid3rqn.world import (Camera, integrate_arc, inverse_warp_numpy, make_scene,
                             relative_transform, render_batch, sample_start_pose)


# %%
def as_sequence(data) -> Sequence:
    return Sequence(data["rgb"], data["flight"], data["K"], data["depth"], data["pose"])


# %%
def warp_rows(seed: int = 0, height: int = 64, width: int = 208):
    """[(name, target, second image, |error| (H, W), valid (H, W))] for the previous frame
    warped with the true depth and motion, not warped, and warped with half the depth."""
    cam = Camera(height, width)
    scene = make_scene("basic", seed)
    pose_s = sample_start_pose(scene, np.random.default_rng(seed))   # the previous frame
    pose_t = integrate_arc(pose_s, 2.0, 0.25, 0.4)          # 0.4 s later at 2 m/s, turning
    rgb, depth = render_batch(scene, np.stack([pose_t, pose_s]), cam)
    target, source = rgb[0].astype(np.float32) / 255, rgb[1].astype(np.float32) / 255
    T = relative_transform(pose_t, pose_s)
    rows = []
    for name, d, warp in [("true depth, true motion", depth[0], True),
                          ("no warp", depth[0], False), ("depth x 0.5", depth[0] * 0.5, True)]:
        warped, valid = inverse_warp_numpy(source, d, cam.K, T) if warp else \
            (source, np.ones(d.shape, bool))
        rows.append((name, target, warped, np.abs(target - warped).mean(axis=2), valid))
    return rows


# %%
def warp_picture(path, seed: int = 0, height: int = 128) -> Path:
    """``warp_rows`` as a picture; the mean |error| of each row is printed on it."""
    lines = []
    for name, target, warped, err, valid in warp_rows(seed):
        e = np.where(valid, err, np.nan)
        err_rgb = viz.colormap(np.nan_to_num(e, nan=0.0), "magma", 0.0, 0.3)
        err_rgb[~valid] = (40, 90, 160)                   # blue: the warp fell off the image
        lines.append(viz.hstack([
            viz.label(viz.resize(viz.to_rgb(target), height), "target I_t"),
            viz.label(viz.resize(viz.to_rgb(warped), height), f"source: {name}"),
            viz.label(viz.resize(err_rgb, height), f"|error| mean {np.nanmean(e):.3f}")],
            height))
        print(f"   {name:<24} mean |error| {np.nanmean(e):.3f}")
    gap = np.full((6, lines[0].shape[1], 3), 255, np.uint8)
    return write_image(path, np.concatenate([x for line in lines for x in (line, gap)][:-1]))


# %%
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help="a tiny run, for the tests")
    parser.add_argument("--seed", type=int, default=0, help="worlds, weights and batches")
    parser.add_argument("--out", default="runs/examples/03_train_depth",
                        help="folder for the pictures")
    parser.add_argument("--iterations", type=int, default=800, help="training iterations")
    args = parser.parse_args([] if "ipykernel" in sys.modules else None)
    out = Path(args.out)
    print("0. the previous frame warped into the target (GT depth and motion):")
    print(f"   -> {warp_picture(out / 'warp.png', args.seed)}")
    frames, test_frames, iterations, every = (60, 20, 4, 2) if args.smoke else \
        (1500, 200, args.iterations, max(args.iterations // 4, 1))

    print(f"1. collecting {frames} training and {test_frames} held-out frames (basic world)")
    train = as_sequence(collect("basic", frames, seed=args.seed, progress=False))
    test = as_sequence(collect("basic", test_frames, seed=args.seed + 1000, progress=False))
    print(f"   {len(train)} frames in {train.flight.max() + 1} flights, "
          f"{len(train.triplet_indices())} triplets")

    print(f"2. training DispNet + PoseNet for {iterations} iterations (batch 4)")
    cfg = TrainConfig(iterations=iterations, seed=args.seed, log_every=every)
    trainer = Trainer(train, cfg)
    shown = test.rgb[:1], test.depth[:1]
    rows = []

    def report(tr, row):
        est = DepthEstimator(tr.disp, 1.0)
        r = evaluate(est, test)
        loss = f"loss {row['loss']:.4f}" if "loss" in row else "(untrained) "
        print(f"   it {row['iteration']:5d}  {loss}  abs rel {r['abs_rel']:.3f}"
              f"  delta<1.25 {r['a1']:.3f}")
        rows.append(est.predict(shown[0])[0])

    report(trainer, {"iteration": 0})
    trainer.run(progress=False, callback=report)

    n = len(rows)
    path = comparison_picture(np.repeat(shown[0], n, 0), np.stack(rows),
                              np.repeat(shown[1], n, 0), out / "emerging.png")
    print(f"3. one held-out frame, a row per report (RGB | predicted | GT): {path}")


# %%
if __name__ == "__main__":
    main()
