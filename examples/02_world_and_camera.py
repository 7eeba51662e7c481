# %% [markdown]
# # 02: the world and its camera
#
# Build each scenario, fly the oracle a few steps through the environment every flight
# of the package uses (``minid3rqn.world.DroneEnv``), and save what the camera sees.
#
# For every scenario it writes ``world_<scenario>.png``: the top view with the flight,
# the drone and its field of view (left), and the camera's RGB frame above its
# ground-truth depth, red near to blue far (right, enlarged 4x). Then ``fov.png``: one
# pose with many obstacles in view, seen by a 90, 60 and 45 degree camera (the image
# keeps its size, only the focal length changes: exercise 3), one row each: top view
# with the field of view | camera RGB | GT depth. Runs in seconds.
#
#     python examples/02_world_and_camera.py [--out runs/examples/02_world_and_camera] [--seed 0]
#     python examples/02_world_and_camera.py --out docs/img     # the pictures of the docs
#     python examples/02_world_and_camera.py --smoke            # fewer steps

# %%
import argparse
import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from minid3rqn import viz
from minid3rqn.rl.policies import OraclePolicy
from minid3rqn.world import (SCENARIOS, Camera, DroneEnv, depth_to_rgb, make_scene,
                             render_batch, sample_start_pose, topdown)

# %% [markdown]
# ## Pictures
#
# One panel per scenario: the top view of flight 0 beside its camera frame and its GT
# depth. The env holds the flights' state: ``env.scenes`` (their worlds) and
# ``env.poses`` (x, y, yaw).

# %%


def panel(env, trajectory, rgb, depth, scale=4):
    """Top view | (RGB over depth), one image."""
    top = topdown(env.scenes[0], trajectory, env.poses[0], env.camera, size=360)
    h, w = rgb.shape[:2]
    cam = Image.new("RGB", (w * scale, 2 * h * scale + 24), (255, 255, 255))
    cam.paste(Image.fromarray(rgb).resize((w * scale, h * scale), Image.NEAREST), (0, 12))
    cam.paste(Image.fromarray(depth_to_rgb(depth)).resize((w * scale, h * scale), Image.NEAREST),
              (0, h * scale + 24))
    draw = ImageDraw.Draw(cam)
    draw.text((2, 0), "camera RGB", fill=(0, 0, 0))
    draw.text((2, h * scale + 12), "GT depth (red near, blue far)", fill=(0, 0, 0))
    out = Image.new("RGB", (top.width + cam.width + 8, max(top.height, cam.height)), (255,) * 3)
    out.paste(top, (0, 0))
    out.paste(cam, (top.width + 8, 0))
    return out


# %% [markdown]
# ## The field of view
#
# The same pose seen by three cameras of one image size: a narrower view is a longer
# focal length, so each pixel covers less of the world.

# %%
def fov_picture(path, seed: int = 0, fovs=(90.0, 60.0, 45.0), height: int = 256):
    """The same pose seen with each horizontal field of view in ``fovs`` (degrees): the
    pose of 48 random ones in a basic world with the most varied depth along the horizon
    and nothing closer than 1.5 m."""
    scene = make_scene("basic", seed)
    rng = np.random.default_rng(seed)
    poses = np.stack([sample_start_pose(scene, rng) for _ in range(48)])
    _, d = render_batch(scene, poses, Camera(16, 52, 90.0))
    horizon = d[:, 7:9].mean(axis=1)                       # (48, 52): depth along the horizon
    varied = np.abs(np.diff(np.clip(horizon, 0, 10), axis=1)).sum(axis=1)
    pose = poses[int(np.argmax(np.where(horizon.min(axis=1) > 1.5, varied, -np.inf)))]
    rows = []
    for fov in fovs:
        cam = Camera(64, 208, fov)
        rgb, depth = render_batch(scene, pose[None], cam)
        top = np.asarray(topdown(scene, pose=pose, camera=cam, size=300, fov_range=8.0))
        rows.append(viz.hstack([viz.label(viz.resize(top, height), f"{fov:g} deg"),
                                viz.label(viz.resize(rgb[0], height), "camera"),
                                viz.label(viz.resize(depth_to_rgb(depth[0], 1.5, 10.0), height),
                                          "GT depth (red near, blue far)")], height))
    gap = np.full((6, rows[0].shape[1], 3), 255, np.uint8)
    Image.fromarray(np.concatenate([x for r in rows for x in (r, gap)][:-1])).save(path)
    return path


# %% [markdown]
# ## Run it
#
# Each scenario's first flight of ``DroneEnv(name, seed=0)``: a world of the training
# pool, a random free start, the oracle for ``--steps`` steps.

# %%
def main(argv=None):
    parser = argparse.ArgumentParser(description="Each scenario and what its camera sees")
    parser.add_argument("--out", default="runs/examples/02_world_and_camera",
                        help="folder for the pictures")
    parser.add_argument("--seed", type=int, default=0, help="world seed")
    parser.add_argument("--steps", type=int, default=12, help="steps the oracle flies")
    parser.add_argument("--smoke", action="store_true", help="3 steps, a quick check")
    args = parser.parse_args([] if argv is None and "ipykernel" in sys.modules else argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    steps = 3 if args.smoke else args.steps
    for name in SCENARIOS:
        # one flight (n_envs=1), observing the RGB frame; the oracle reads the map
        env = DroneEnv(name, 1, seed=args.seed, observation="rgb", camera=Camera(32, 104))
        oracle = OraclePolicy()
        obs, info = env.reset()
        oracle.reset(env)
        trajectory = [env.poses[0].copy()]
        for _ in range(steps):
            obs, reward, terminated, truncated, info = env.step(oracle.act(obs))
            trajectory.append(env.poses[0].copy())
            if terminated[0] or truncated[0]:
                break
        path = out / f"world_{name}.png"
        depth = env.gt_depth()[0]                       # what the camera's rays measured
        panel(env, np.array(trajectory), obs[0], depth).save(path)
        print(f"{name:14s} world seed {info['scene_seed'][0]}: {len(trajectory) - 1} steps, "
              f"d_nearest {info['d_nearest'][0]:.2f} m, depth {depth.min():.2f}.."
              f"{depth.max():.2f} m -> {path}")
    print(f"the same pose at 90, 60 and 45 degrees -> {fov_picture(out / 'fov.png', args.seed)}")


if __name__ == "__main__":
    main()
