# %% [markdown]
# # 09: What motion alone says about depth: the plane sweep, next to the DispNet
#
# A DispNet reads depth from one frame's appearance. Two frames filmed 0.8 m apart also
# carry it in their parallax, and a plane sweep reads it out without any learning. For
# target pixel p and each hypothesis depth d_k (k = 1..D), put the point at depth d_k on
# p's ray, move it into the previous camera with the known motion and project it there
# (the warp of the paper's Eq. 3, with the depth map set to d_k):
#
#     p'_k = proj(K T_{t->t-1} d_k K^-1 p)
#     cost_k(p) = |B_t(p) - B_{t-1}(p'_k)|,     B the brightness (mean of R, G, B) / 255
#
# At the pixel's true depth both frames see the same surface, so the cost is small there:
# the depth of the lowest cost is the sweep's answer (``plane_sweep`` below, a few lines
# of NumPy). This example measures how good that answer is, in fresh `basic` worlds
# flown by the late-turning pilot, with the true motion between the frames (odometry):
#
# 1. For every pixel with a previous frame in its flight: the sweep's answer (the
#    lowest of D = 12 costs) and the shipped DispNet's depth (its own metric scale),
#    each scored as the share of pixels within 25 % of the truth, by true distance and
#    for the outer thirds of the columns (where the parallax is) and the middle third
#    (the flight direction, where a point hardly moves in the image).
# 2. A picture: RGB | the sweep's answer | the DispNet's depth | GT depth.
#
# At 32x104 pixels and with the world's evenly coloured surfaces the sweep's answer is
# weak, and weakest straight ahead, where a drone needs it most. One exception: under
# 2 m straight ahead (a wall close in front, example 06's case) the sweep is right about
# twice as often as the DispNet (0.41 against 0.22 of the pixels, seed 77), though still
# wrong more often than right.
#
#     python examples/09_plane_sweep.py [--smoke] [--frames 400] [--seed 77] \
#         [--out runs/examples/09_plane_sweep]
#
# Ground truth is used only to score; nothing is trained.

# %%
"""What motion alone says about depth: the plane sweep, next to the DispNet."""
import argparse
import sys
from pathlib import Path

import numpy as np

from minid3rqn.depth.data import Sequence, collect
from minid3rqn.depth.evaluate import DepthEstimator
from minid3rqn.io import MODELS, write_image
from minid3rqn.viz import depth_to_rgb
from minid3rqn.world.geometry import inverse_warp_numpy, relative_transform

BINS = ((0.5, 2.0), (2.0, 4.0), (4.0, 7.0), (7.0, 12.0))
WITHIN = np.log(1.25)             # "within 25 %": |ln(answer / truth)| < ln 1.25


# %%
def sweep_depths(n_planes: int, near: float = 0.5, far: float = 12.0) -> np.ndarray:
    """The D hypothesis depths, nearest first, evenly spaced in inverse depth (parallax
    is proportional to 1 / depth, so equal steps in it are equal steps in the image)."""
    return 1.0 / np.linspace(1.0 / near, 1.0 / far, n_planes)


# %%
def plane_sweep(frame, prev, T_to_prev, K, depths) -> np.ndarray:
    """Costs (N, H, W, D) of frames (N, H, W, 3) uint8 against the frames before them,
    T_to_prev (N, 4, 4) = T_{t->t-1}: for each depth d_k, the brightness difference
    between the frame and the previous frame read where d_k puts each pixel (bilinear,
    clamped to the border: every cost is a real difference)."""
    bright = lambda rgb: rgb.mean(axis=-1) / 255.0
    plane = np.ones(frame.shape[:3])
    costs = [np.abs(bright(frame) - inverse_warp_numpy(bright(prev), d * plane, K,
                                                       T_to_prev, "border")[0])
             for d in depths]
    return np.stack(costs, axis=-1)


# %%
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=400, help="frames flown (fresh worlds)")
    ap.add_argument("--seed", type=int, default=77)
    ap.add_argument("--planes", type=int, default=12, help="depths swept, 0.5-12 m")
    ap.add_argument("--out", default="runs/examples/09_plane_sweep", help="folder for the picture")
    ap.add_argument("--smoke", action="store_true", help="60 frames: a quick check")
    args = ap.parse_args([] if "ipykernel" in sys.modules else None)
    frames = 60 if args.smoke else args.frames

    data = collect("basic", n_frames=frames, seed=args.seed, late=0.5, progress=False)
    seq = Sequence(data["rgb"], data["flight"], data["K"], data["depth"], data["pose"])
    idx = np.flatnonzero(np.r_[False, seq.flight[1:] == seq.flight[:-1]])  # has a previous
    motion = relative_transform(seq.pose[idx], seq.pose[idx - 1])          # T_{t->t-1}

    depths = sweep_depths(args.planes)
    cost = plane_sweep(seq.rgb[idx], seq.rgb[idx - 1], motion, seq.K, depths)
    sweep = depths[cost.argmin(axis=-1)]                                   # (N, H, W)
    dispnet = DepthEstimator.load(MODELS / "depth_basic.npz").predict(seq.rgb[idx])
    truth = seq.depth[idx]

    w = truth.shape[2]
    columns = np.zeros(w, bool)
    columns[w // 3:2 * w // 3] = True                                      # middle third
    print(f"{len(idx)} frames with a previous one ({frames} flown, seed {args.seed}); "
          f"share of pixels within 25 % of the truth:")
    print(f"{'GT depth (m)':>14}  {'columns':>12}  {'pixels':>7}  {'sweep':>6}  {'DispNet':>7}")
    for lo, hi in BINS:
        for name, cols in (("outer thirds", ~columns), ("middle third", columns)):
            ok = (truth >= lo) & (truth < hi) & cols[None, None, :]
            if not ok.any():
                continue
            hit = lambda d: np.mean(np.abs(np.log(d[ok] / truth[ok])) < WITHIN)
            print(f"{lo:>5.1f} - {hi:<5.1f}  {name:>12}  {ok.sum():>7}  {hit(sweep):>6.2f}  "
                  f"{hit(dispnet):>7.2f}")

    from PIL import Image
    rows = np.linspace(0, len(idx) - 1, 4).astype(int)
    picture = np.concatenate([np.concatenate(
        [seq.rgb[idx[r]], depth_to_rgb(sweep[r]), depth_to_rgb(dispnet[r]),
         depth_to_rgb(truth[r])], axis=1) for r in rows], axis=0)
    out = Path(args.out) / "plane_sweep.png"
    write_image(out, Image.fromarray(picture).resize((picture.shape[1] * 3,
                                                      picture.shape[0] * 3), Image.NEAREST))
    print(f"wrote {out}: RGB | the sweep's answer | DispNet | GT, one frame per row")


# %%
if __name__ == "__main__":
    main()
