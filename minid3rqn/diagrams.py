"""Pictures of the networks and of the pipeline, drawn with Pillow from the nets themselves.

Nothing here is drawn by hand: each figure builds the network from its config, runs one
forward pass on a zero input (no graph recorded) and reads, layer by layer, the shape
that came out and the number of weights the layer holds. The boxes are those numbers.

    python -m minid3rqn.diagrams                  # writes docs/img/net_*.png, pipeline.png
    python -m minid3rqn.diagrams --out runs/img   # elsewhere

Each PNG also carries its figure's text (the layers, shapes and weight counts) as a
PNG text chunk ``minid3rqn``, so a test can tell whether a committed picture is the one
today's code draws.

    trace(net, *inputs)   -> [Layer(name, kind, shape, weights)], in the order they ran
    qnet_layers(cfg)      -> the boxes of a QNet: conv torso, LSTM (or FC), dueling head
    dispnet_layers(), posenet_layers(), pipeline_parts()
"""
from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont
from PIL.PngImagePlugin import PngInfo

from . import autograd as ag
from .io import write_image
from .nets.layers import LSTM, Conv2d, Linear
from .nets.module import Module

OUT = Path("docs/img")
TEXT_KEY = "minid3rqn"


# -- reading a network ------------------------------------------------------------------
@dataclass
class Layer:
    name: str            # dotted path of the layer in its net: convs.0, core, heads.2
    kind: str            # "conv 4x4 s2", "LSTM 704 -> 128", "linear 128 -> 5"
    shape: tuple         # the output's shape, batch (and time) axes dropped
    weights: int         # parameters of this layer (weights and biases)


def layers_of(module: Module, prefix: str = ""):
    """(dotted name, layer) of every Conv2d, Linear and LSTM inside ``module``."""
    for name, value in vars(module).items():
        items = [(f"{prefix}{name}", value)] if isinstance(value, Module) else \
            [(f"{prefix}{name}.{i}", v) for i, v in enumerate(value)
             if isinstance(v, Module)] if isinstance(value, (list, tuple)) else []
        for full, sub in items:
            if isinstance(sub, (Conv2d, Linear, LSTM)):
                yield full, sub
            else:
                yield from layers_of(sub, full + ".")


def kind_of(layer: Module) -> str:
    if isinstance(layer, Conv2d):
        kh, kw = layer.weight.shape[2:]
        pad = f" pad {layer.padding}" if layer.padding else ""
        return f"conv {kh}x{kw} s{layer.stride}{pad}"
    if isinstance(layer, LSTM):
        return f"LSTM {layer.input_size} -> {layer.hidden_size}"
    return f"linear {layer.in_features} -> {layer.out_features}"


def trace(net: Module, *inputs, batch_axes: int = 1, **kwargs) -> list[Layer]:
    """Run ``net(*inputs, **kwargs)`` once without a graph and record every layer it calls:
    its name, kind, output shape (the first ``batch_axes`` axes dropped) and weights."""
    found, named = [], dict(layers_of(net))
    for name, layer in named.items():
        def recording(*args, _layer=layer, _name=name, _forward=layer.forward, **kw):
            out = _forward(*args, **kw)
            y = out[0] if isinstance(out, tuple) else out
            weights = int(sum(p.size for p in _layer.parameters()))
            found.append(Layer(_name, kind_of(_layer), tuple(y.shape[batch_axes:]), weights))
            return out
        layer.forward = recording            # an instance attribute: Module.__call__ finds it
    try:
        with ag.no_grad():
            net(*inputs, **kwargs)
    finally:
        for layer in named.values():
            del layer.forward
    return found


def count(net: Module) -> int:
    return int(sum(p.size for p in net.parameters()))


def shape_text(shape) -> str:
    """(4, 15, 51) -> "4 x 15x51" (channels x rows x columns); (128,) -> "128"."""
    if len(shape) == 3:
        return f"{shape[0]} x {shape[1]}x{shape[2]}"
    return "x".join(map(str, shape))


# -- the nets' boxes --------------------------------------------------------------------
def shipped_qnet_config(name: str = "d3rqn_basic"):
    """The QNetConfig of a shipped Q-net file (minid3rqn/models/<name>.npz)."""
    from .io import read_metadata
    from .nets.qnet import QNetConfig
    meta = read_metadata(Path(__file__).parent / "models" / f"{name}.npz")
    return QNetConfig(**meta["qnet_config"])


def qnet_layers(config=None) -> dict:
    """The boxes of a QNet (default: the shipped paper-recipe D3RQN's config), from one
    forward pass of one time step: {"title", "boxes": [[lines], ...], "total"}; a box
    that is a list of boxes is drawn side by side (the dueling head's V and A)."""
    from .nets.qnet import QNet, variant_name
    config = config or shipped_qnet_config()
    net = QNet(config, rng=0)
    obs = np.zeros((1, 1, config.in_channels, config.height, config.width_px), np.float32)
    layers = {x.name: x for x in trace(net, obs, batch_axes=1)}
    boxes = [["input: depth frame" + ("s" if config.in_channels > 1 else ""),
              shape_text((config.in_channels, config.height, config.width_px))]]
    for i in range(len(config.convs)):
        x = layers[f"convs.{i}"]
        boxes.append([f"{x.kind} + ReLU", shape_text(x.shape), f"{x.weights:,} weights"])
    boxes.append(["flatten", f"{net.n_features} features"])
    core = layers["core"]
    boxes.append([core.kind + ("" if config.recurrent else " + ReLU"),
                  "(h, c) carried from step to step" if config.recurrent else "one step",
                  f"{core.weights:,} weights"])
    if config.dueling:
        v, a = layers["value"], layers["advantage"]
        boxes.append([["value V", v.kind, f"{v.weights:,} weights"],
                      ["advantage A", a.kind, f"{a.weights:,} weights"]])
        boxes.append(["Q = V + A - mean_a A", f"{config.n_actions} Q-values"])
    else:
        q = layers["q_head"]
        boxes.append(["Q", q.kind, f"{q.weights:,} weights"])
    return {"title": f"QNet ({variant_name(config).upper()}): {count(net):,} weights",
            "boxes": boxes, "total": count(net)}


def depth_nets():
    """The DispNet and PoseNet that depth training builds (``depth.train.build_nets``)."""
    from .depth.train import TrainConfig, build_nets
    return build_nets(TrainConfig())


def dispnet_layers(height: int = 32, width: int = 104) -> dict:
    """The boxes of the DispNet depth training builds: {"title", "encoder": [lines per
    level], "decoder": [lines per level, finest first], "heads": [lines per scale],
    "total", "input"}."""
    disp, _ = depth_nets()
    layers = {x.name: x for x in trace(disp, np.zeros((1, 3, height, width), np.float32))}
    n = len(disp.enc_a)
    encoder = []
    for k in range(n):
        a, b = layers[f"enc_a.{k}"], layers[f"enc_b.{k}"]
        encoder.append([f"level {k}: conv 3x3 s2, conv 3x3, ELU", shape_text(b.shape),
                        f"{a.weights + b.weights:,} weights"])
    decoder = [None] * n
    for j in range(n):
        i = n - 1 - j
        a, b = layers[f"dec_a.{j}"], layers[f"dec_b.{j}"]
        skip = f" + skip from level {i - 1}" if i > 0 else ""
        decoder[i] = [f"conv, up x2{skip}, conv", shape_text(b.shape),
                      f"{a.weights + b.weights:,} weights"]
    heads = []
    for i in range(disp.n_scales):
        h = layers[f"heads.{i}"]
        heads.append([f"disp_{i} = {disp.disp_scale:g} sigmoid(conv) + {disp.min_disp:g}",
                      shape_text(h.shape), f"{h.weights:,} weights"])
    return {"title": f"DispNet: {count(disp):,} weights; depth = 1 / disp_0 at "
                     f"{height}x{width}", "input": ["input: RGB frame",
                                                    shape_text((3, height, width))],
            "encoder": encoder, "decoder": decoder, "heads": heads, "total": count(disp)}


def posenet_layers(height: int = 32, width: int = 104) -> dict:
    """The boxes of the PoseNet depth training builds (a chain, like ``qnet_layers``)."""
    _, pose = depth_nets()
    frame = np.zeros((1, 3, height, width), np.float32)
    layers = {x.name: x for x in trace(pose, frame, [frame] * pose.n_sources)}
    boxes = [[f"input: target + {pose.n_sources} sources, stacked",
              shape_text((3 * (1 + pose.n_sources), height, width))]]
    for i in range(len(pose.convs)):
        x = layers[f"convs.{i}"]
        boxes.append([f"{x.kind} + ReLU", shape_text(x.shape), f"{x.weights:,} weights"])
    head = layers["head"]
    boxes.append([head.kind, shape_text(head.shape), f"{head.weights:,} weights"])
    boxes.append([f"mean over the image, x {pose.pose_scale:g}",
                  f"{pose.n_sources} x 6: (tx, ty, tz, rx, ry, rz) of T_t->s"])
    return {"title": f"PoseNet: {count(pose):,} weights", "boxes": boxes,
            "total": count(pose)}


def pipeline_parts(seed: int = 0) -> dict:
    """What the pipeline figure shows: a rendered camera frame, the shipped DispNet's depth
    of the last 5 frames of a short flight, the Q-net's size and the action table."""
    from .depth.evaluate import DepthEstimator
    from .world import ACTIONS, Camera, integrate_arc, make_scene, render_batch, \
        sample_start_pose
    cam = Camera()
    scene = make_scene("basic", seed)
    pose = sample_start_pose(scene, np.random.default_rng(seed))
    poses = [pose]
    for _ in range(4):
        poses.append(integrate_arc(poses[-1], float(ACTIONS[0, 0]), 0.1, 0.4))
    rgb, _ = render_batch(scene, np.stack(poses), cam)
    est = DepthEstimator.load(Path(__file__).parent / "models" / "depth_basic.npz")
    depth = est.predict(rgb)
    q = qnet_layers()
    disp = dispnet_layers(cam.height, cam.width)
    rates = ", ".join(f"{w:+g}" if w else "0" for w in ACTIONS[:, 1])
    text = {"camera": ["camera", f"RGB 3 x {cam.height}x{cam.width}, every 0.4 s"],
            "dispnet": ["DispNet", f"{disp['total']:,} weights", "depth = scale / disp_0"],
            "window": ["a depth map a step", f"1 x {cam.height}x{cam.width}; trained on 5"],
            "qnet": ["D3RQN", f"{q['total']:,} weights", "its LSTM state carries",
                     f"the past; {len(ACTIONS)} Q-values"],
            "action": ["yaw rate of argmax_a Q", f"{rates} rad/s",
                       f"at {ACTIONS[0, 0]:g} m/s"]}
    return {"title": "The pipeline: one camera -> DispNet -> depth maps (windows of 5) -> D3RQN "
                     "-> a yaw rate", "text": text, "rgb": rgb[-1], "depth": depth}


# -- two real pieces of autograd graph ----------------------------------------------------
def lstm_step_ops(x, h, c, weight_ih, weight_hh, bias, record: dict | None = None):
    """One LSTM step written with basic ops, line by line the formulas of
    ``autograd/lstm.py`` (which computes the same in one fused op with its own backward)::

        z = x W_ih^T + h W_hh^T + b;  i, f, g, o = s(z_i), s(z_f), tanh(z_g), s(z_o)
        c' = f c + i g;  h' = o tanh(c')

    ``record``: a dict that receives the intermediate tensors by name (z, i, f, g, o, c').
    """
    hidden = c.shape[-1]
    z = x @ weight_ih.T + h @ weight_hh.T + bias
    i = ag.sigmoid(z[:, :hidden])
    f = ag.sigmoid(z[:, hidden:2 * hidden])
    g = ag.tanh(z[:, 2 * hidden:3 * hidden])
    o = ag.sigmoid(z[:, 3 * hidden:])
    c_new = f * c + i * g
    if record is not None:
        record.update({"z": z, "i": i, "f": f, "g": g, "o": o, "c'": c_new})
    return o * ag.tanh(c_new), c_new


def lstm_step_graph(config=None):
    """(h', names): one step of the shipped D3RQN's LSTM on its conv features, composed of
    basic ops so that the graph shows each formula; the weights are the net's own."""
    from .nets.qnet import QNet
    net = QNet(config or shipped_qnet_config(), rng=0)
    x = ag.Tensor(np.zeros((1, net.n_features), np.float32))
    h, c = net.core.initial_state(1)
    names = {"x (conv features)": x, "h": h, "c": c,
             **{f"core.{k}": p for k, p in net.core.named_parameters()}}
    h_new, _ = lstm_step_ops(x, h, c, net.core.weight_ih, net.core.weight_hh, net.core.bias,
                             record=names)
    names["h'"] = h_new
    return h_new, names


def dueling_head_graph(config=None):
    """(Q, names): the shipped D3RQN's dueling head ``QNet.head`` on one LSTM output z."""
    from .nets.qnet import QNet
    net = QNet(config or shipped_qnet_config(), rng=0)
    z = ag.Tensor(np.zeros((1, net.config.width), np.float32))
    names = {"z (LSTM output)": z, **{k: p for k, p in net.named_parameters()
                                      if k.startswith(("value", "advantage"))}}
    return net.head(z), names


# -- drawing ----------------------------------------------------------------------------
INK, BOX, EDGE, NOTE = (20, 20, 20), (232, 240, 252), (60, 90, 150), (90, 90, 90)
FILL = {"conv": (232, 240, 252), "LSTM": (252, 236, 220), "linear": (236, 248, 232)}


def font(size: int = 13):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:                  # Pillow < 10.1: the small bitmap font only
        return ImageFont.load_default()


def fill_of(lines) -> tuple:
    first = lines[0] + (lines[1] if len(lines) > 1 else "")
    return next((c for k, c in FILL.items() if k in first), (245, 245, 245))


def draw_box(d: ImageDraw.ImageDraw, box, lines, big, small) -> None:
    x0, y0, x1, y1 = box
    d.rounded_rectangle(box, radius=6, fill=fill_of(lines), outline=EDGE, width=2)
    fonts = [big] + [small] * (len(lines) - 1)
    heights = [f.getbbox("Ag")[3] + 3 for f in fonts]
    y = (y0 + y1) / 2 - sum(heights) / 2
    for text, f, h in zip(lines, fonts, heights):
        w = d.textlength(text, font=f)
        d.text(((x0 + x1) / 2 - w / 2, y), text, fill=INK if f is big else NOTE, font=f)
        y += h


def arrow(d: ImageDraw.ImageDraw, p0, p1, colour=EDGE, width: int = 2) -> None:
    (x0, y0), (x1, y1) = p0, p1
    d.line([p0, p1], fill=colour, width=width)
    v = np.array([x1 - x0, y1 - y0], float)
    v /= max(np.linalg.norm(v), 1e-9)
    n = np.array([-v[1], v[0]])
    tip = np.array([x1, y1])
    d.polygon([tuple(tip), tuple(tip - 9 * v + 4.5 * n), tuple(tip - 9 * v - 4.5 * n)],
              fill=colour)


def chain_image(fig: dict, width: int = 560, box_h: int = 58, gap: int = 22) -> Image.Image:
    """A vertical chain of boxes (a box that is a list of boxes: side by side)."""
    big, small, title = font(14), font(12), font(15)
    top = 40
    height = top + len(fig["boxes"]) * (box_h + gap) + 4
    im = Image.new("RGB", (width, height), "white")
    d = ImageDraw.Draw(im)
    d.text((12, 10), fig["title"], fill=INK, font=title)
    y, above = top, [(width / 2, None)]
    for lines in fig["boxes"]:
        parts = lines if isinstance(lines[0], list) else [lines]
        span = (width - 40) / len(parts)
        here = []
        for k, part in enumerate(parts):
            x0 = 20 + k * span + (8 if len(parts) > 1 else 0)
            x1 = 20 + (k + 1) * span - (8 if len(parts) > 1 else 0)
            draw_box(d, (x0, y, x1, y + box_h), part, big, small)
            here.append(((x0 + x1) / 2, y))
        for xa, ya in above:
            if ya is None:
                continue
            for xb, yb in here:
                arrow(d, (xa, ya), (xb, yb - 2))
        above = [(x, y + box_h) for x, _ in here]
        y += box_h + gap
    return im


def dispnet_image(fig: dict, box_w: int = 250, box_h: int = 58, gap: int = 26) -> Image.Image:
    """The encoder down the left, the decoder up the middle, the heads on the right; skip
    connections as horizontal arrows."""
    big, small, title = font(13), font(12), font(15)
    n = len(fig["encoder"])
    xs = [20, 20 + box_w + 60, 20 + 2 * box_w + 120]
    top = 40
    row_y = [top + r * (box_h + gap) for r in range(n + 1)]
    im = Image.new("RGB", (xs[2] + box_w + 20, row_y[-1] + box_h + 16), "white")
    d = ImageDraw.Draw(im)
    d.text((12, 10), fig["title"], fill=INK, font=title)

    def box(col, row, lines):
        b = (xs[col], row_y[row], xs[col] + box_w, row_y[row] + box_h)
        draw_box(d, b, lines, big, small)
        return b

    inp = box(0, 0, fig["input"])
    enc = [box(0, k + 1, lines) for k, lines in enumerate(fig["encoder"])]
    dec = [box(1, i, lines) for i, lines in enumerate(fig["decoder"])]
    for k, b in enumerate(enc):                              # down the encoder
        prev = inp if k == 0 else enc[k - 1]
        arrow(d, ((prev[0] + prev[2]) / 2, prev[3]), ((b[0] + b[2]) / 2, b[1] - 2))
    last = enc[-1]                                           # the bottleneck to the decoder
    arrow(d, (last[2], (last[1] + last[3]) / 2), (dec[-1][0] + 30, dec[-1][3] + 2))
    for i in range(n - 1, 0, -1):                            # up the decoder
        arrow(d, ((dec[i][0] + dec[i][2]) / 2, dec[i][1]),
              ((dec[i - 1][0] + dec[i - 1][2]) / 2, dec[i - 1][3] + 2))
    for i in range(1, n):                                    # skips: level i-1 -> decoder i
        s = enc[i - 1]
        arrow(d, (s[2], (s[1] + s[3]) / 2), (dec[i][0] - 2, (dec[i][1] + dec[i][3]) / 2),
              colour=(150, 150, 150))
    for i, lines in enumerate(fig["heads"]):
        h = box(2, i, lines)
        arrow(d, (dec[i][2], (dec[i][1] + dec[i][3]) / 2), (h[0] - 2, (h[1] + h[3]) / 2))
    return im


def pipeline_image(parts: dict) -> Image.Image:
    """Camera frame -> DispNet -> the 5 depth maps -> D3RQN -> the yaw rate, left to right."""
    from .viz import depth_to_rgb, resize
    big, small, title = font(14), font(12), font(15)
    zoom_h, box_w, box_h, gap = 64, 160, 84, 30
    rgb = resize(parts["rgb"], zoom_h)
    maps = [resize(depth_to_rgb(m), zoom_h // 2) for m in parts["depth"]]
    col_w = [rgb.shape[1], box_w, maps[0].shape[1] + 4 * 6, box_w + 10, box_w + 30]
    x = [16]
    for w in col_w[:-1]:
        x.append(x[-1] + w + gap)
    width, top = x[-1] + col_w[-1] + 16, 44
    mid = top + 20 + box_h / 2
    im = Image.new("RGB", (width, int(top + box_h + 70)), "white")
    d = ImageDraw.Draw(im)
    d.text((12, 10), parts["title"], fill=INK, font=title)
    t = parts["text"]
    im.paste(Image.fromarray(rgb), (x[0], int(mid - zoom_h / 2)))
    for k, line in enumerate(t["camera"]):
        d.text((x[0], mid + zoom_h / 2 + 4 + 15 * k), line, fill=INK if k == 0 else NOTE,
               font=big if k == 0 else small)
    for k, m in enumerate(maps):                              # a stack, newest in front
        im.paste(Image.fromarray(m), (x[2] + 6 * (len(maps) - 1 - k),
                                      int(mid - zoom_h / 2 + 6 * k)))
    for k, line in enumerate(t["window"]):
        d.text((x[2], mid + zoom_h / 2 + 4 + 15 * k), line, fill=INK if k == 0 else NOTE,
               font=big if k == 0 else small)
    boxes = {}
    for col, key in ((1, "dispnet"), (3, "qnet"), (4, "action")):
        b = (x[col], mid - box_h / 2, x[col] + col_w[col], mid + box_h / 2)
        draw_box(d, b, t[key], big, small)
        boxes[col] = b
    ends = [x[0] + col_w[0], boxes[1][2], x[2] + col_w[2], boxes[3][2]]
    starts = [boxes[1][0], x[2], boxes[3][0], boxes[4][0]]
    for a, b in zip(ends, starts):
        arrow(d, (a + 4, mid), (b - 4, mid))
    return im


GRAPH_FILL = {"op": (232, 240, 252), "leaf": (253, 227, 200), "constant": (238, 238, 238)}


def graph_image(nodes, title: str = "", box_w: int = 128, box_h: int = 40,
                gap_x: int = 14, gap_y: int = 30) -> Image.Image:
    """A picture of an autograd graph (``autograd.graph``'s nodes): inputs at the top,
    each op one row below its lowest parent; ops blue, inputs that need a gradient
    orange, the others grey; each box gives the op (or input) and its output's shape."""
    big, small, head = font(12), font(11), font(14)
    depth = []
    for n in nodes:
        depth.append(1 + max((depth[p] for p in n.parents), default=-1))
    for n in nodes:                                    # an input: just above its first use
        if not n.parents:
            uses = [depth[m.index] for m in nodes if n.index in m.parents]
            depth[n.index] = min(uses, default=1) - 1
    rows = {}
    for n, r in zip(nodes, depth):
        rows.setdefault(r, []).append(n)
    widest = max(len(r) for r in rows.values())
    width = max(widest * (box_w + gap_x) + gap_x, 420)
    top = 34 if title else 10
    legend = 22
    im = Image.new("RGB", (width, top + len(rows) * (box_h + gap_y) + legend), "white")
    d = ImageDraw.Draw(im)
    if title:
        d.text((10, 8), title, fill=INK, font=head)
    where = {}
    for r, row in sorted(rows.items()):
        span = len(row) * (box_w + gap_x) - gap_x
        x = (width - span) / 2
        y = top + r * (box_h + gap_y)
        for n in row:
            where[n.index] = (x, y)
            x += box_w + gap_x
    row_of = {n.index: r for n, r in zip(nodes, depth)}
    line = (120, 140, 180)
    for n in nodes:                                    # edges first, under the boxes
        xb, yb = where[n.index]
        for k, p in enumerate(n.parents):
            xa, ya = where[p]
            start = (xa + box_w / 2, ya + box_h)
            end = (xb + box_w / 2 + (k - (len(n.parents) - 1) / 2) * 10, yb - 1)
            between = [where[m.index][0] for m in nodes
                       if row_of[p] < row_of[m.index] < row_of[n.index]]
            if between:                # past the rows in between, round their boxes
                left, right = min(between) - gap_x / 2, max(between) + box_w + gap_x / 2
                side = left if start[0] + end[0] < left + right else right
                path = [start, (start[0], ya + box_h + gap_y / 2),
                        (side, ya + box_h + gap_y / 2), (side, yb - gap_y / 2),
                        (end[0], yb - gap_y / 2)]
                d.line(path, fill=line, width=1)
                start = path[-1]
            arrow(d, start, end, colour=line, width=1)
    for n in nodes:
        x, y = where[n.index]
        d.rounded_rectangle((x, y, x + box_w, y + box_h), radius=5, fill=GRAPH_FILL[n.kind],
                            outline=EDGE, width=1)
        name = " = ".join(filter(None, (n.name, n.op))) if n.kind == "op" else n.title()
        lines = [f"#{n.index} {name}", str(n.shape)]
        for k, (text, f) in enumerate(zip(lines, (big, small))):
            while d.textlength(text, font=f) > box_w - 6 and len(text) > 4:
                text = text[:-2] + "~"
            w = d.textlength(text, font=f)
            d.text((x + box_w / 2 - w / 2, y + 5 + 17 * k), text, fill=INK if k == 0 else NOTE,
                   font=f)
    y = im.height - legend + 4
    x = 10
    for kind, text in (("op", "op"), ("leaf", "input that needs a gradient"),
                       ("constant", "input that needs none")):
        d.rectangle((x, y, x + 14, y + 12), fill=GRAPH_FILL[kind], outline=EDGE)
        d.text((x + 19, y), text, fill=NOTE, font=small)
        x += 28 + d.textlength(text, font=small)
    return im


def save(im: Image.Image, path, text: dict) -> Path:
    """Write ``im`` with its figure's text in the PNG text chunk ``minid3rqn``."""
    info = PngInfo()
    info.add_text(TEXT_KEY, json.dumps(text, sort_keys=True))
    return write_image(path, im, pnginfo=info)


def figure_text(path) -> dict | None:
    """The text a PNG written by ``save`` carries (None if it carries none)."""
    with Image.open(path) as im:
        im.load()
        text = im.text.get(TEXT_KEY) if hasattr(im, "text") else None
    return json.loads(text) if text else None


def figures() -> dict:
    """{file name: (figure's text, drawing function)} of every figure of the nets."""
    q, disp, pose = qnet_layers(), dispnet_layers(), posenet_layers()
    pipe = pipeline_parts()
    pipe_text = {"title": pipe["title"], "text": pipe["text"]}
    graphs = {}
    for name, build, title in (
            ("graph_lstm_step.png", lstm_step_graph,
             "One LSTM step of the D3RQN, written with basic ops: h' = o tanh(f c + i g)"),
            ("graph_dueling_head.png", dueling_head_graph,
             "The D3RQN's dueling head: Q = V(z) + A(z) - mean_a A(z)")):
        root, names = build()
        nodes = ag.graph(root, names)
        graphs[name] = ({"title": title, "graph": ag.graph_text(root, names)},
                        lambda nodes=nodes, title=title: graph_image(nodes, title))
    return {**graphs,
            "net_qnet.png": (q, lambda: chain_image(q)),
            "net_dispnet.png": (disp, lambda: dispnet_image(disp)),
            "net_posenet.png": (pose, lambda: chain_image(pose)),
            "pipeline.png": (pipe_text, lambda: pipeline_image(pipe))}


def draw_all(out=OUT, only=None) -> list[Path]:
    """Draw every figure (or those named in ``only``) into ``out``."""
    done = []
    for name, (text, draw) in figures().items():
        if only and name not in only:
            continue
        done.append(save(draw(), Path(out) / name, text))
    return done


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(OUT), help="folder for the PNGs (default: %(default)s)")
    args = p.parse_args(argv)
    for path in draw_all(args.out):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
