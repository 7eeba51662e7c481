"""Pictures with Pillow only: colour maps, image strips, GIFs, bar charts and curves.

Every function takes NumPy arrays and returns uint8 RGB arrays (H, W, 3) or writes a
file; nothing here needs matplotlib.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont
from PIL.PngImagePlugin import PngInfo

from .io import write_image

# Control points of a perceptual colour map (sampled from the published magma).
_MAPS = {
    "magma": [(0, 0, 4), (28, 16, 68), (79, 18, 123), (129, 37, 129), (181, 54, 122),
              (229, 80, 100), (251, 135, 97), (254, 194, 135), (252, 253, 191)],
}


def colormap(values: np.ndarray, name: str = "magma", vmin=None, vmax=None) -> np.ndarray:
    """Map a 2-D array to RGB uint8 (H, W, 3) by linear interpolation in a colour map."""
    if name not in _MAPS:
        raise ValueError(f"colormap: name must be one of {sorted(_MAPS)}; got {name!r}")
    v = np.asarray(values, dtype=np.float64)
    lo = np.nanmin(v) if vmin is None else vmin
    hi = np.nanmax(v) if vmax is None else vmax
    t = np.clip((v - lo) / (hi - lo if hi > lo else 1.0), 0.0, 1.0)
    t = np.nan_to_num(t)
    pts = np.asarray(_MAPS[name], dtype=np.float64)
    x = t * (len(pts) - 1)
    i = np.minimum(x.astype(int), len(pts) - 2)
    f = (x - i)[..., None]
    return np.rint(pts[i] * (1 - f) + pts[i + 1] * f).astype(np.uint8)


# Depth colour map, as in the paper's figures: red near -> yellow -> green -> cyan -> blue far.
_DEPTH_RAMP = np.array([[0.85, 0.10, 0.10], [0.95, 0.80, 0.15], [0.25, 0.80, 0.30],
                        [0.20, 0.75, 0.90], [0.15, 0.20, 0.80]])


def depth_to_rgb(depth, near: float = 0.5, far: float = 12.0, log: bool = False) -> np.ndarray:
    """Depth (..., H, W) in metres -> (..., H, W, 3) uint8, red at ``near``, blue at ``far``.

    Linear in depth, or in log depth with ``log=True`` (more colours for near things);
    values outside [near, far] are clipped.
    """
    lowest = 0.0 if not log else np.nextafter(0.0, 1.0)  # log depth needs near > 0
    if not lowest <= near < far:
        raise ValueError(f"depth_to_rgb: need 0 <= near < far (0 < near with log=True); "
                         f"got near={near}, far={far}")
    d = np.clip(np.asarray(depth, np.float64), near, far)
    if log:
        d, near, far = np.log(d), np.log(near), np.log(far)
    x = (d - near) / (far - near) * (len(_DEPTH_RAMP) - 1)            # 0 near .. 4 far
    i = np.minimum(np.floor(x).astype(int), len(_DEPTH_RAMP) - 2)
    w = (x - i)[..., None]
    ramp = _DEPTH_RAMP
    return ((ramp[i] * (1 - w) + ramp[i + 1] * w) * 255 + 0.5).astype(np.uint8)


def depth_key(width: int, near: float = 0.5, far: float = 12.0,
              height: int = 24) -> np.ndarray:
    """The colour key of ``depth_to_rgb(..., near, far)`` (linear in depth): a bar from
    ``near`` (left) to ``far`` (right) in its colours, with ticks in metres under it;
    (height, width, 3) uint8. The ticks fall on a simple step (0.5, 1, 2, 5 ... m; at
    most six), the ends included."""
    x = np.linspace(0.0, 1.0, width)
    metres = near + x * (far - near)
    im = Image.new("RGB", (width, height), (255, 255, 255))
    im.paste(Image.fromarray(depth_to_rgb(np.repeat(metres[None], 8, 0), near, far)))
    draw, font = ImageDraw.Draw(im), ImageFont.load_default()
    step = next(s for s in (0.5, 1, 2, 5, 10, 20, 50, 100) if (far - near) / s <= 5)
    inside = np.arange(np.ceil(near / step) * step, far, step)
    gap = step / 2
    ticks = [near, *(float(t) for t in inside if near + gap < t < far - gap), far]
    for k, t in enumerate(ticks):
        u = (t - near) / (far - near)
        px = int(round(u * (width - 1)))
        text = f"{t:g}" + (" m" if k == len(ticks) - 1 else "")
        w = draw.textlength(text, font=font)
        draw.line([(px, 8), (px, 10)], fill=(0, 0, 0))
        draw.text((min(max(px - w / 2, 0), width - w), 11), text, fill=(0, 0, 0), font=font)
    return np.asarray(im)


def resize(img: np.ndarray, height: int, width: int | None = None) -> np.ndarray:
    """Nearest-neighbour resize of an RGB/grey uint8 image to (height, width)."""
    im = Image.fromarray(np.asarray(img))
    if width is None:
        width = max(1, round(im.width * height / im.height))
    return np.asarray(im.resize((int(width), int(height)), Image.NEAREST))


def to_rgb(img: np.ndarray) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype != np.uint8:
        a = np.clip(np.rint(a * 255 if a.max() <= 1.0 else a), 0, 255).astype(np.uint8)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    return a


def hstack(images, height: int, gap: int = 4, fill=255) -> np.ndarray:
    """Resize every image to ``height`` rows and put them side by side."""
    parts = []
    for k, im in enumerate(images):
        if k:
            parts.append(np.full((height, gap, 3), fill, np.uint8))
        parts.append(resize(to_rgb(im), height))
    return np.concatenate(parts, axis=1)


def label(img: np.ndarray, text: str, xy=(3, 2), color=(255, 255, 255)) -> np.ndarray:
    """Draw ``text`` on a copy of ``img``."""
    im = Image.fromarray(to_rgb(img).copy())
    ImageDraw.Draw(im).text(xy, text, fill=color, font=ImageFont.load_default())
    return np.asarray(im)


def bar_chart(values, names, size=(160, 120), highlight: int | None = None,
              title: str = "") -> np.ndarray:
    """Vertical bars (e.g. Q-values per action), zero line included, as an RGB image."""
    w, h = size
    im = Image.new("RGB", (w, h), (255, 255, 255))
    d = ImageDraw.Draw(im)
    font = ImageFont.load_default()
    v = np.asarray(values, dtype=np.float64)
    lo, hi = min(0.0, float(v.min())), max(0.0, float(v.max()))
    span = hi - lo if hi > lo else 1.0
    top, bottom = 16, h - 14
    zero = bottom - (0 - lo) / span * (bottom - top)
    bw = (w - 8) / len(v)
    for k, val in enumerate(v):
        x0 = 4 + k * bw + 2
        y = bottom - (val - lo) / span * (bottom - top)
        colour = (220, 80, 40) if k == highlight else (70, 110, 180)
        d.rectangle([x0, min(y, zero), x0 + bw - 4, max(y, zero)], fill=colour)
        d.text((x0, bottom + 1), str(names[k])[:5], fill=(0, 0, 0), font=font)
    d.line([4, zero, w - 4, zero], fill=(0, 0, 0))
    if title:
        d.text((4, 2), title, fill=(0, 0, 0), font=font)
    return np.asarray(im)


def write_gif(frames, path, fps: float = 5.0) -> Path:
    """Write frames (RGB uint8 arrays or PIL images, one size) as a looping GIF
    (atomically: ``io.write_file``)."""
    ims = [f if isinstance(f, Image.Image) else Image.fromarray(to_rgb(f)) for f in frames]
    if not ims:
        raise ValueError("write_gif: frames is empty")
    return write_image(path, ims[0], save_all=True, append_images=ims[1:],
                       duration=int(1000 / fps), loop=0, optimize=False)


_COLOURS = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14),
            (23, 190, 207)]


def line_plot(series: dict, path=None, size=(520, 300), title: str = "", xlabel: str = "",
              ylabel: str = "", ylim=None) -> np.ndarray:
    """Plot {name: (x, y)} as lines with axes, ticks and a legend; optionally save a PNG."""
    w, h = size
    im = Image.new("RGB", (w, h), (255, 255, 255))
    d = ImageDraw.Draw(im)
    font = ImageFont.load_default()
    left, right, top, bottom = 52, w - 10, 22, h - 34
    xs = [np.asarray(x, float) for x, _ in series.values()]
    ys = [np.asarray(y, float) for _, y in series.values()]
    allx = np.concatenate(xs) if xs else np.zeros(1)
    ally = np.concatenate(ys) if ys else np.zeros(1)
    ally = ally[np.isfinite(ally)] if np.isfinite(ally).any() else np.zeros(1)
    x0, x1 = float(allx.min()), float(allx.max())
    y0, y1 = (float(ally.min()), float(ally.max())) if ylim is None else ylim
    if x1 <= x0:
        x1 = x0 + 1
    if y1 <= y0:
        y1 = y0 + 1

    def px(x, y):
        return (left + (x - x0) / (x1 - x0) * (right - left),
                bottom - (y - y0) / (y1 - y0) * (bottom - top))

    d.rectangle([left, top, right, bottom], outline=(0, 0, 0))
    for k in range(5):
        yv = y0 + k * (y1 - y0) / 4
        _, yy = px(x0, yv)
        d.line([left - 3, yy, left, yy], fill=(0, 0, 0))
        d.line([left + 1, yy, right - 1, yy], fill=(235, 235, 235))
        d.text((2, yy - 5), f"{yv:.3g}", fill=(0, 0, 0), font=font)
        xv = x0 + k * (x1 - x0) / 4
        xx, _ = px(xv, y0)
        d.line([xx, bottom, xx, bottom + 3], fill=(0, 0, 0))
        d.text((xx - 12, bottom + 5), f"{xv:.3g}", fill=(0, 0, 0), font=font)
    for k, (name, (x, y)) in enumerate(series.items()):
        colour = _COLOURS[k % len(_COLOURS)]
        pts = [px(a, b) for a, b in zip(np.asarray(x, float), np.asarray(y, float))
               if np.isfinite(b)]
        if len(pts) > 1:
            d.line(pts, fill=colour, width=2)
        elif pts:
            d.ellipse([pts[0][0] - 2, pts[0][1] - 2, pts[0][0] + 2, pts[0][1] + 2], fill=colour)
        d.text((left + 6, top + 4 + 12 * k), name, fill=colour, font=font)
    if title:
        d.text((left, 5), title, fill=(0, 0, 0), font=font)
    if xlabel:
        d.text(((left + right) / 2 - 3 * len(xlabel), h - 14), xlabel, fill=(0, 0, 0), font=font)
    if ylabel:
        d.text((2, 5), ylabel, fill=(0, 0, 0), font=font)
    arr = np.asarray(im)
    if path is not None:
        write_image(path, im)
    return arr


def learning_curve_png(rows, path, title: str = "") -> Path:
    """Two panels from training-curve rows: episode return, and success rate, vs steps.
    The title is drawn and also kept as the PNG's text chunk "Title"."""
    steps = [r["steps"] for r in rows]
    ret = line_plot({"episode return": (steps, [r["return"] for r in rows])},
                    title=title, xlabel="environment steps")
    suc = line_plot({"success rate (training flights)": (steps, [r["success"] for r in rows])},
                    xlabel="environment steps", ylim=(0.0, 1.0))
    info = PngInfo()
    info.add_text("Title", title)
    return write_image(path, np.concatenate([ret, suc], axis=0), pnginfo=info)
