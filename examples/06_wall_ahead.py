# %% [markdown]
# # 06: Where single-frame depth fails: a wall close ahead, and why
#
# Every DispNet we trained sees an obstacle under 2 m straight ahead about twice too far
# (docs/depth.md section 7). This example finds out why, with the shipped DispNet and
# fresh `basic` worlds flown by a late-turning pilot, in four steps:
#
# 1. Frames whose middle columns show one surface (depth spread under 30 %): the
#    DispNet's depth there (its own metric scale) against the truth, by distance.
#    Beyond about 3 m it follows the truth; closer, it says about 2.8 m whatever the
#    truth is.
# 2. Is it reading texture size? Re-render those frames with the obstacle textures k
#    times larger (a wall at Z with texture k looks much like one at Z / k). The answer
#    hardly moves: no.
# 3. Is it reading where the wall meets the floor (the cue van Dijk and de Croon, ICCV
#    2019, found in KITTI networks)? At altitude h the floor at image row v lies at
#    h / y_n(v); the lowest row sees the floor at about 3.35 m, so a nearer wall covers the
#    whole column and its foot is out of view. Lower the camera to 0.5 m (the network
#    still assumes 1 m): the foot of walls down to 1.6 m comes back into view, and for
#    those walls the answer moves with the truth again, about twice too far (1 / 0.5,
#    the altitude ratio). Closer than 1.6 m it is stuck again.
# 4. Does view synthesis know the right answer? The photometric error of those near
#    pixels, warped from the previous and next frames with the GT pose and their GT
#    depth times alpha, is lowest at alpha = 1. The training signal is there; a single
#    frame does not carry the cue the network would need to follow it.
#
#     python examples/06_wall_ahead.py [--smoke] [--worlds 80] [--model M] \
#         [--out runs/examples/06_wall_ahead]
#
# The frames are filmed with the world's default camera, the one every shipped DispNet
# was trained with: its horizon in the middle row. A camera with the horizon raised
# (`Camera(horizon_row=4)`) sees the floor from 1.93 m ahead instead of 3.35 m, and a
# DispNet trained on its frames answers step 1 for walls down to about 2 m.
#
# Writes wall_ahead.png: RGB | predicted | GT depth (metres on one fixed colour scale,
# red 0.5 m, blue 10 m) for some near-wall frames. Ground truth is used only to look;
# nothing is trained.

# %%
"""Where single-frame depth fails: a wall close ahead, and why."""
import argparse
import copy
import sys
from pathlib import Path

import numpy as np

from minid3rqn.depth.data import fly
from minid3rqn.depth.evaluate import DepthEstimator
from minid3rqn.io import MODELS
from minid3rqn.io import write_image
from minid3rqn.viz import depth_to_rgb
from minid3rqn.world import Camera, make_scene, render_batch
from minid3rqn.world import textures as tx
from minid3rqn.world.geometry import inverse_warp_numpy, relative_transform

MODEL = MODELS / "depth_basic.npz"
MIDDLE = slice(46, 58)          # the 12 middle columns of 104: straight ahead
BINS = (0.5, 1.0, 1.5, 2.0, 2.5, 3.5, 6.0)
ALPHAS = (0.5, 0.7, 0.85, 1.0, 1.2, 1.5, 2.0, 2.5)


# %%
def flights(n_worlds: int, seed: int):
    """(scene, poses) of one late-turning flight in each of n fresh basic worlds (world
    seeds 5000 + k: not used in training)."""
    rng = np.random.default_rng(seed)
    for k in range(n_worlds):
        scene = make_scene("basic", seed=5000 + k)
        yield scene, fly(scene, 50, rng, late=0.5)


# %%
def variant(scene, texture_scale: float = 1.0, altitude: float | None = None):
    """A copy of ``scene`` with the obstacle textures ``texture_scale`` times larger (the
    floor and the ceiling, appearance rows 0 and 1, are left alone) and the camera at
    ``altitude`` metres."""
    out = copy.copy(scene)
    table = scene.appearances.copy()
    table[2:, [tx.SU, tx.SV, tx.NOISE_SCALE]] *= texture_scale
    out.appearances = table
    if altitude is not None:
        out.altitude = altitude
    out._cache = {}                     # the renderer caches per-scene constants
    return out


# %%
def one_surface_ahead(depth):
    """Frames whose middle columns show one surface: (F,) bool, and its median depth."""
    mid = depth[:, :, MIDDLE]
    lo, hi = mid.min(axis=(1, 2)), mid.max(axis=(1, 2))
    return (hi < 1.3 * lo) & (hi < BINS[-1]), np.median(mid, axis=(1, 2))


# %%
def by_distance(est, worlds, cam, texture_scale=1.0, altitude=None):
    """Median GT and predicted depth of the middle columns for every one-surface frame."""
    gt, pred, frames = [], [], []
    for scene, poses in worlds:
        rgb, depth = render_batch(variant(scene, texture_scale, altitude), poses, cam)
        ok, g = one_surface_ahead(depth)
        if ok.any():
            p = est.predict(rgb[ok])
            gt.append(g[ok])
            pred.append(np.median(p[:, :, MIDDLE], axis=(1, 2)))
            frames.append((rgb[ok], p, depth[ok]))
    return np.concatenate(gt), np.concatenate(pred), frames


# %%
def print_bins(gt, pred, indent="     "):
    for lo, hi in zip(BINS[:-1], BINS[1:]):
        m = (gt >= lo) & (gt < hi)
        if m.any():
            print(f"{indent}GT {lo:3.1f}-{hi:3.1f} m  ({m.sum():3d} frames): predicted "
                  f"{np.median(pred[m]):4.2f} m, {np.median(pred[m] / gt[m]):4.2f} x the truth")


# %%
def photometric_curve(worlds, cam):
    """Mean L1 photometric error (min over the previous and next frame, as training
    uses) of the pixels under 2 m in the middle quarter of the view, when their GT depth
    is scaled by each alpha; GT relative pose."""
    K, total, count = cam.K, np.zeros(len(ALPHAS)), np.zeros(len(ALPHAS))
    a = np.array(ALPHAS)[:, None, None]
    for scene, poses in worlds:
        rgb, depth = render_batch(scene, poses, cam)
        rgb = rgb.astype(np.float32) / 255
        for t in range(1, len(poses) - 1):
            near = np.zeros(depth[t].shape, bool)
            near[:, 39:65] = depth[t][:, 39:65] < 2.0
            if near[:, 39:65].mean() < 0.8:
                continue
            scaled = np.where(near, depth[t] * a, depth[t])           # (alphas, H, W)
            best = np.full(scaled.shape, np.inf)
            for s in (t - 1, t + 1):
                T = np.broadcast_to(relative_transform(poses[t], poses[s]), (len(a), 4, 4))
                src = np.broadcast_to(rgb[s], (len(a),) + rgb[s].shape)
                warped, valid = inverse_warp_numpy(src, scaled, K, T)
                err = np.where(valid, np.abs(warped - rgb[t]).mean(-1), np.inf)
                best = np.minimum(best, err)
            e = best[:, near]
            total += np.where(np.isfinite(e), e, 0).sum(1)
            count += np.isfinite(e).sum(1)
    return total / np.maximum(count, 1), int(count[ALPHAS.index(1.0)])


# %%
def picture(frames, path, n=6):
    """RGB | predicted | GT for the n nearest one-surface frames, fixed metric colours."""
    rgb = np.concatenate([f[0] for f in frames])
    pred = np.concatenate([f[1] for f in frames])
    gt = np.concatenate([f[2] for f in frames])
    order = np.argsort(np.median(gt[:, :, MIDDLE], axis=(1, 2)))[:n]
    white = np.full((rgb.shape[1], 3, 3), 255, np.uint8)
    rows = [np.concatenate([rgb[i], white, depth_to_rgb(pred[i], 0.5, 10.0, log=True), white,
                            depth_to_rgb(gt[i], 0.5, 10.0, log=True)], axis=1) for i in order]
    gap = np.full((3, rows[0].shape[1], 3), 255, np.uint8)
    img = np.concatenate([x for r in rows for x in (r, gap)][:-1])
    return write_image(path, img.repeat(3, 0).repeat(3, 1))


# %%
def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--smoke", action="store_true", help="a few worlds (seconds)")
    p.add_argument("--worlds", type=int, default=80, help="fresh basic worlds, one flight each")
    p.add_argument("--seed", type=int, default=0, help="the pilot's seed")
    p.add_argument("--model", default=str(MODEL), help="the DispNet .npz")
    p.add_argument("--out", default="runs/examples/06_wall_ahead", help="folder for the picture")
    args = p.parse_args([] if "ipykernel" in sys.modules else None)
    est = DepthEstimator.load(args.model)
    worlds = list(flights(6 if args.smoke else args.worlds, args.seed))
    cam, altitude = Camera(), worlds[0][0].altitude
    lowest_row = (cam.height - 1 - cam.cy) / cam.fy          # y_n of the lowest row (centre)
    print(f"{len(worlds)} late-turning flights, {sum(len(q) for _, q in worlds)} frames "
          f"(seed {args.seed}). Camera at {altitude:.1f} m: the lowest image row sees the "
          f"floor at {altitude / lowest_row:.2f} m.")

    print("\n1. One surface across the middle of the view: the DispNet's depth (metric) "
          "by true distance")
    gt, pred, frames = by_distance(est, worlds, cam)
    print_bins(gt, pred)
    path = picture(frames, Path(args.out) / "wall_ahead.png")

    print("\n2. The same frames with obstacle textures k times larger (walls under 2 m):")
    for k in (0.5, 1.0, 2.0):
        g, q, _ = by_distance(est, worlds, cam, texture_scale=k)
        m = g < 2.0
        if m.any():
            print(f"     k = {k:3.1f}: predicted {np.median(q[m]):4.2f} m, "
                  f"{np.median(q[m] / g[m]):4.2f} x the truth ({m.sum()} frames)")

    low = 0.5
    print(f"\n3. The camera lowered to {low} m (the lowest row now sees the floor at "
          f"{low / lowest_row:.2f} m; the network assumes {altitude:.1f} m):")
    g, q, _ = by_distance(est, worlds, cam, altitude=low)
    print_bins(g, q)

    print("\n4. Photometric error of the near pixels ahead, GT pose, GT depth x alpha:")
    curve, pixels = photometric_curve(worlds, cam)
    print("     alpha " + " ".join(f"{a:6.2f}" for a in ALPHAS))
    print("     error " + " ".join(f"{c:6.4f}" for c in curve)
          + f"   lowest at alpha = {ALPHAS[int(np.argmin(curve))]} ({pixels} pixels)")
    print(f"\npicture: {path}")


# %%
if __name__ == "__main__":
    main()
