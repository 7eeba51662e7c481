"""A top-down map of a world with the drone, its trajectory and its field of view (Pillow)."""
from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw

from .camera import Camera
from .scene import Scene
from .textures import C0, C1

def topdown(scene: Scene, trajectory=None, pose=None, camera: Camera | None = None,
            size: int = 400, fov_range: float = 6.0, margin: float = 1.0) -> Image.Image:
    """A top view of ``scene``: floor, obstacles in their base colours, the flight path
    (polyline of (x, y[, yaw]) points, ``trajectory``), the drone at ``pose`` (x, y, yaw)
    with its 0.5 m collision circle and, given ``camera``, its field-of-view wedge drawn
    ``fov_range`` metres long. ``size`` is the longer side in pixels; north is up."""
    if not isinstance(scene, Scene):
        raise TypeError(f"topdown: scene must be a Scene; got {type(scene).__name__}")
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 16:
        raise ValueError(f"topdown: size must be an int >= 16; got {size!r}")
    lo = scene.bounds[:2] - margin
    span = scene.bounds[2:] + margin - lo
    scale = size / span.max()
    w, h = int(np.ceil(span[0] * scale)), int(np.ceil(span[1] * scale))

    def px(xy):
        xy = np.asarray(xy, float).reshape(-1, 2)
        return [(float((x - lo[0]) * scale), float(h - (y - lo[1]) * scale)) for x, y in xy]

    img = Image.new("RGB", (w, h), (40, 40, 44))
    draw = ImageDraw.Draw(img)
    floor = tuple(int(v * 255 * 0.8) for v in scene.appearances[0, C0])
    draw.polygon(px(scene.region_outer), fill=floor)
    for hole in scene.region_holes:
        draw.polygon(px(hole), fill=(40, 40, 44))

    def colour(app):
        c = 0.6 * scene.appearances[app, C0] + 0.4 * scene.appearances[app, C1]
        return tuple(int(v * 255) for v in c)

    for c, r, app in zip(scene.circle_centres, scene.circle_radii, scene.circle_app):
        (x, y), = px(c)
        draw.ellipse([x - r * scale, y - r * scale, x + r * scale, y + r * scale],
                     fill=colour(app), outline=(0, 0, 0))
    for verts, app in zip(scene.poly_verts, scene.poly_app):
        draw.polygon(px(verts), fill=colour(app), outline=(0, 0, 0))
    width = max(2, int(round(0.15 * scale)))
    for a, b, app in zip(scene.wall_a, scene.wall_b, scene.wall_app):
        draw.line(px([a, b]), fill=colour(app), width=width)
    if trajectory is not None:
        t = np.asarray(trajectory, float)
        if t.ndim != 2 or t.shape[1] < 2:
            raise ValueError(f"topdown: trajectory must be (T, 2) or (T, 3); got shape {t.shape}")
        if len(t) > 1:
            draw.line(px(t[:, :2]), fill=(255, 255, 255), width=max(1, width // 2))
    if pose is not None:
        x, y, yaw = np.asarray(pose, float)
        if camera is not None:
            half = np.radians(camera.hfov_deg) / 2
            ends = [(x + fov_range * np.cos(yaw + a) / np.cos(half),
                     y + fov_range * np.sin(yaw + a) / np.cos(half)) for a in (half, -half)]
            overlay = Image.new("RGBA", img.size, (0, 0, 0, 0))
            ImageDraw.Draw(overlay).polygon(px([(x, y)] + ends), fill=(255, 255, 120, 70))
            img = Image.alpha_composite(img.convert("RGBA"), overlay).convert("RGB")
            draw = ImageDraw.Draw(img)
        (cx, cy), = px((x, y))
        r = 0.5 * scale
        draw.ellipse([cx - r, cy - r, cx + r, cy + r], outline=(255, 60, 60), width=2)
        draw.line(px([(x, y), (x + 0.9 * np.cos(yaw), y + 0.9 * np.sin(yaw))]),
                  fill=(255, 60, 60), width=2)
    return img
