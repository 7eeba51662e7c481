"""Pictures for the docs that no other command makes.

    python -m minid3rqn.classroom.pictures [--out docs/img] [--seed 0]

writes ``fov.png`` (exercise 3): the same pose seen with a 90, 60 and 45 degree
camera, one row each: top view with the field-of-view wedge | camera RGB | ground-truth
depth (red near, blue far); and ``warp.png``: three rows, each
target | second image | |difference|:

    1. the previous frame warped into the target with the TRUE depth and motion
       (p_s ~ K T_{t->s} D_t(p_t) K^-1 p_t, the paper's Eq. 3): the error is small,
       except where the source did not see the target's pixels;
    2. the previous frame as it is (no warp): the camera moved, so the error is large;
    3. warped with the depth halved (a wrong depth): the error comes back.

This is what trains DispNet: the only depth that makes row 1's error small is the
right one.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def warp_rows(seed: int = 0, height: int = 64, width: int = 208):
    from ..world import Camera, make_scene, render_batch, sample_start_pose
    from ..world import inverse_warp_numpy, relative_transform
    from ..world import integrate_arc
    cam = Camera(height, width)
    scene = make_scene("basic", seed)
    rng = np.random.default_rng(seed)
    pose_s = sample_start_pose(scene, rng)                  # the previous frame (source)
    pose_t = integrate_arc(pose_s, 2.0, 0.25, 0.4)          # 0.4 s later at 2 m/s, turning
    rgb, depth = render_batch(scene, np.stack([pose_t, pose_s]), cam)
    target, source = rgb[0].astype(np.float32) / 255, rgb[1].astype(np.float32) / 255
    T = relative_transform(pose_t, pose_s)
    rows = []
    for name, d, warp in [("true depth, true motion", depth[0], True),
                          ("no warp", depth[0], False),
                          ("depth x 0.5", depth[0] * 0.5, True)]:
        if warp:
            warped, valid = inverse_warp_numpy(source, d, cam.K, T)
        else:
            warped, valid = source, np.ones(d.shape, bool)
        err = np.abs(target - warped).mean(axis=2)
        rows.append((name, target, warped, err, valid))
    return rows


def make_warp_picture(path, seed: int = 0, zoom: int = 2) -> Path:
    from .. import viz
    rows = warp_rows(seed)
    h = rows[0][1].shape[0] * zoom
    lines = []
    for name, target, warped, err, valid in rows:
        e = np.where(valid, err, np.nan)
        err_rgb = viz.colormap(np.nan_to_num(e, nan=0.0), "magma", 0.0, 0.3)
        err_rgb[~valid] = (40, 90, 160)                   # blue: the warp fell off the image
        mean = float(np.nanmean(e))
        panels = [viz.label(viz.resize(viz.to_rgb(target), h), "target I_t"),
                  viz.label(viz.resize(viz.to_rgb(warped), h), f"source: {name}"),
                  viz.label(viz.resize(err_rgb, h), f"|error| mean {mean:.3f}")]
        lines.append(viz.hstack(panels, h))
    return _save_rows(lines, path)


def _save_rows(lines, path) -> Path:
    """Stack picture rows (same width) with white gaps and write them as a PNG."""
    from PIL import Image
    gap = np.full((6, lines[0].shape[1], 3), 255, np.uint8)
    out = np.concatenate([x for line in lines for x in (line, gap)][:-1], axis=0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(out).save(path)
    return path


def make_fov_picture(path, seed: int = 0, fovs=(90.0, 60.0, 45.0), zoom: int = 2) -> Path:
    from .. import viz
    from ..world import Camera, make_scene, render_batch, sample_start_pose
    from ..world import depth_to_rgb, topdown
    scene = make_scene("basic", seed)
    rng = np.random.default_rng(seed)
    poses = np.stack([sample_start_pose(scene, rng) for _ in range(48)])
    _, d = render_batch(scene, poses, Camera(16, 52, 90.0))
    horizon = d[:, 7:9].mean(axis=1)                          # (24, 52) depth along the horizon
    varied = np.abs(np.diff(np.clip(horizon, 0, 10), axis=1)).sum(axis=1)
    score = np.where(horizon.min(axis=1) > 1.5, varied, -np.inf)
    pose = poses[int(np.argmax(score))]           # many obstacles at several distances in view
    h = 32 * 2 * zoom
    lines = []
    for fov in fovs:
        cam = Camera(64, 208, fov)
        rgb, depth = render_batch(scene, pose[None], cam)
        top = np.asarray(topdown(scene, pose=pose, camera=cam, size=300, fov_range=8.0))
        panels = [viz.label(viz.resize(top, h * 2), f"{fov:g} deg"),
                  viz.label(viz.resize(rgb[0], h * 2), "camera"),
                  viz.label(viz.resize(depth_to_rgb(depth[0], 1.5, 10.0), h * 2),
                            "GT depth (red near, blue far)")]
        lines.append(viz.hstack(panels, h * 2))
    return _save_rows(lines, path)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="docs/img")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    print(make_warp_picture(Path(args.out) / "warp.png", args.seed))
    print(make_fov_picture(Path(args.out) / "fov.png", args.seed))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
