"""Build each scenario, fly the oracle a few steps, save what the camera sees.

For every scenario it writes ``world_<scenario>.png``: the top view with the flight, the
drone and its field of view (left), and the camera's RGB frame above its ground-truth
depth, red near to blue far (right, enlarged 4x). Runs in seconds.

    python examples/02_world_and_camera.py --out docs/img --seed 0
    python examples/02_world_and_camera.py --smoke            # fewer steps, into ./out
"""
import argparse
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from minid3rqn.world import SCENARIOS, Camera, DroneEnv, Oracle, depth_to_rgb, topdown


def panel(env, trajectory, rgb, depth, scale=4):
    """Top view | (RGB over depth), one image."""
    top = topdown(env.scene, trajectory, env.pose, env.camera, size=360)
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


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="output folder (default docs/img, "
                                                    "or ./out with --smoke)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=12)
    parser.add_argument("--smoke", action="store_true", help="3 steps, a quick check")
    args = parser.parse_args(argv)
    out = Path(args.out or ("out" if args.smoke else "docs/img"))
    out.mkdir(parents=True, exist_ok=True)
    steps = 3 if args.smoke else args.steps
    for name in SCENARIOS:
        env = DroneEnv(name, seed=args.seed, camera=Camera(32, 104))
        oracle = Oracle()
        obs, info = env.reset()
        trajectory = [info["pose"]]
        for _ in range(steps):
            obs, reward, terminated, truncated, info = env.step(int(oracle(env)[0]))
            trajectory.append(info["pose"])
            if terminated or truncated:
                break
        path = out / f"world_{name}.png"
        panel(env, np.array(trajectory), obs, info["depth"]).save(path)
        print(f"{name:14s} world seed {env.scene_seed}: {len(trajectory) - 1} steps, "
              f"d_nearest {info['d_nearest']:.2f} m, depth {info['depth'].min():.2f}.."
              f"{info['depth'].max():.2f} m -> {path}")


if __name__ == "__main__":
    main()
