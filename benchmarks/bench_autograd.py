"""Forward+backward speed of our autograd at the project's shapes, against PyTorch CPU.

    python benchmarks/bench_autograd.py                  # 1 and 2 threads, all cases
    python benchmarks/bench_autograd.py --threads 1 --cases dispnet,qnet --repeat 20

For each thread count the script re-runs itself in a child process with
OMP_NUM_THREADS / OPENBLAS_NUM_THREADS / MKL_NUM_THREADS set *before* NumPy loads
(OpenBLAS reads them once, at import), and calls ``torch.set_num_threads`` with the
same number, so both sides get the same cores. Every case runs in float32; times are
the best of ``--repeat`` runs after two warm-ups, ours and torch alternating (the
machine may be shared: the minimum is the least disturbed run). "fwd" is inference
(no graph), "f+b" a forward that records the graph plus the backward pass; "ratio"
is ours / torch for f+b (our aim: <= 2.0).

On a busy machine, ``--clock cpu --threads 1`` times with the process's CPU time
instead of the wall clock: preemption by other processes no longer counts (cache and
memory-bandwidth contention still do). It is meaningless with more than one thread
(CPU time adds up over threads).

Cases (all written twice below, once with ``minid3rqn.autograd`` and once with torch):

- ``dispnet``: the DispNet of ``minid3rqn/nets/dispnet.py`` (defaults: encoder
  16-32-64-96, each level conv 3x3 s2 + conv 3x3, ELU; decoder 16-16-32-64, each
  level conv 3x3, nearest upsample x2, crop, concat skip, conv 3x3; sigmoid disparity
  heads at 4 scales) on batch 4 at 32x104 and 64x208.
- ``dispnet-sfm``: an SfMLearner-like variant: encoder kernels 7-5-3-3,
  channels 16-32-64-128, decoder 16-32-64-128, otherwise the same.
- ``qnet``: the conv stack of ``minid3rqn/nets/qnet.py`` (32x104x1 -> conv 4x4 s2
  (4) -> conv 4x4 s2 (8) -> conv 3x3 (8), valid padding, ReLU; the paper's 8x8 s4,
  4x4 s2, 3x3 s2 scaled to our 32x104 maps, where the paper's own would leave a 2x11
  map too small for the last conv) on 32 x 5 = 160 frames, then ``lstm`` (704 ->
  256) over T = 5, B = 32 (when ``minid3rqn.autograd.lstm`` exists).
- ``sample``: ``bilinear_sample`` of 4x3x32x104 images at a perturbed pixel grid,
  gradients to image and coordinates (torch: ``grid_sample``, align_corners=True),
  when ``minid3rqn.autograd.sample`` exists.
- ``gemm``: the ceiling, a 1024^3 float32 ``np.matmul`` in GFLOP/s. The dispnet
  rows note the GFLOP/s reached by the forward pass's convolutions, ours and torch's
  (2 * multiply-adds of all convs / time of the forward with ELU and sigmoid left
  out; upsampling and concatenation, a few percent, stay in).
"""
from __future__ import annotations

import os
import sys
import time

from _timing import CLOCKS, cases_over_threads, fmt, load_torch, measure, print_table

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CASES = ("dispnet", "dispnet-sfm", "qnet", "sample", "gemm")


# -- timing ----------------------------------------------------------------------------
CLOCK = time.perf_counter          # --clock cpu: time.process_time


def _measure(fns: dict, repeat: int) -> dict:
    """Best-of-``repeat`` time in ms of each callable, run round-robin (ours and torch
    alternate, so load from other processes hits both alike). Two warm-ups
    (benchmarks/_timing.py)."""
    return measure(fns, repeat, warmup=2, clock=CLOCK, stat=min)


def _no_grad_torch(torch, fn):
    def run():
        with torch.no_grad():
            fn()
    return run


def _no_grad_ours(fn):
    from minid3rqn.autograd import no_grad

    def run():
        with no_grad():
            fn()
    return run


# -- DispNet, both sides ----------------------------------------------------------------
def _dispnet_spec(variant: str):
    if variant == "dispnet":
        return dict(enc=(16, 32, 64, 96), dec=(16, 16, 32, 64), kernels=(3, 3, 3, 3))
    return dict(enc=(16, 32, 64, 128), dec=(16, 32, 64, 128), kernels=(7, 5, 3, 3))


def _dispnet_weights(spec, rng, np):
    """A list of (weight, bias) in the order the forward uses them."""
    def conv(c_in, c_out, k):
        w = rng.standard_normal((c_out, c_in, k, k)).astype(np.float32)
        return w * np.float32((2.0 / (c_in * k * k)) ** 0.5), np.zeros(c_out, np.float32)
    enc, dec, ks = spec["enc"], spec["dec"], spec["kernels"]
    params, c_in = [], 3
    for c, k in zip(enc, ks):
        params += [conv(c_in, c, k), conv(c, c, 3)]
        c_in = c
    for i in reversed(range(len(enc))):
        skip = enc[i - 1] if i > 0 else 0
        params += [conv(c_in, dec[i], 3), conv(dec[i] + skip, dec[i], 3)]
        c_in = dec[i]
    params += [conv(dec[i], 1, 3) for i in range(len(enc))]
    return params


def _dispnet_forward(x, params, spec, F, cat, crop):
    """The same network for either library: F has conv2d, elu, upsample, sigmoid."""
    enc, ks = spec["enc"], spec["kernels"]
    h, w = x.shape[2:]
    p = iter(params)
    feats = []
    for k in ks:
        wt, b = next(p)
        x = F.elu(F.conv2d(x, wt, b, 2, k // 2))
        wt, b = next(p)
        x = F.elu(F.conv2d(x, wt, b, 1, 1))
        feats.append(x)
    levels = len(enc)
    dec_out = {}
    for i in reversed(range(levels)):
        wt, b = next(p)
        x = F.elu(F.conv2d(x, wt, b, 1, 1))
        x = F.upsample(x, 2)
        th, tw = -(-h // 2 ** i), -(-w // 2 ** i)
        if x.shape[2] != th or x.shape[3] != tw:
            x = crop(x, th, tw)
        if i > 0:
            x = cat([x, feats[i - 1]])
        wt, b = next(p)
        x = F.elu(F.conv2d(x, wt, b, 1, 1))
        dec_out[i] = x
    return [F.sigmoid(F.conv2d(dec_out[i], *next(p), 1, 1)) for i in range(levels)]


def _conv_flops(x_shape, params, spec):
    """2 * multiply-adds of every conv2d in the dispnet forward (for GFLOP/s)."""
    class Shape:  # runs the forward on shapes only
        def __init__(self, s):
            self.shape = tuple(s)

    total = [0]

    class F:
        @staticmethod
        def conv2d(x, w, b, s, p):
            n, _, h, wd = x.shape
            o, c, k, _ = w.shape
            oh, ow = (h + 2 * p - k) // s + 1, (wd + 2 * p - k) // s + 1
            total[0] += 2 * n * o * oh * ow * c * k * k
            return Shape((n, o, oh, ow))
        elu = sigmoid = staticmethod(lambda x: x)
        upsample = staticmethod(lambda x, s: Shape(x.shape[:2] + (2 * x.shape[2], 2 * x.shape[3])))

    _dispnet_forward(Shape(x_shape), params, spec, F,
                     lambda xs: Shape((xs[0].shape[0], sum(t.shape[1] for t in xs)) + xs[0].shape[2:]),
                     lambda x, th, tw: Shape(x.shape[:2] + (th, tw)))
    return total[0]


def bench_dispnet(variant, size, batch, repeat, torch, np):
    from minid3rqn import autograd as ag
    from minid3rqn.autograd import conv as agconv

    spec = _dispnet_spec(variant)
    rng = np.random.default_rng(0)
    params = _dispnet_weights(spec, rng, np)
    x_np = rng.random((batch, 3) + size, dtype=np.float32)
    gs = [rng.standard_normal((batch, 1, -(-size[0] // 2 ** i), -(-size[1] // 2 ** i)))
          .astype(np.float32) for i in range(len(spec["enc"]))]

    class Ours:
        conv2d = staticmethod(agconv.conv2d)
        elu, sigmoid = staticmethod(ag.elu), staticmethod(ag.sigmoid)
        upsample = staticmethod(lambda x, s: agconv.upsample(x, s, "nearest"))

    tensors = [(ag.Tensor(w, requires_grad=True), ag.Tensor(b, requires_grad=True))
               for w, b in params]
    x = ag.Tensor(x_np)

    def ours_forward():
        return _dispnet_forward(x, tensors, spec, Ours, lambda xs: ag.concat(xs, axis=1),
                                lambda t, th, tw: t[:, :, :th, :tw])

    def ours_step():
        outs = ours_forward()
        loss = (outs[0] * gs[0]).sum()
        for o, g in zip(outs[1:], gs[1:]):
            loss = loss + (o * g).sum()
        loss.backward()

    class ConvOnly(Ours):                    # the convolutions alone, for GFLOP/s
        elu = sigmoid = staticmethod(lambda t: t)

    fns = {"ours_fwd": _no_grad_ours(ours_forward), "ours_fb": ours_step,
           "conv_only": _no_grad_ours(lambda: _dispnet_forward(
               x, tensors, spec, ConvOnly, lambda xs: ag.concat(xs, axis=1),
               lambda t, th, tw: t[:, :, :th, :tw]))}
    if torch is not None:
        import torch.nn.functional as tF

        class Theirs:
            conv2d, elu, sigmoid = (staticmethod(tF.conv2d), staticmethod(tF.elu),
                                    staticmethod(torch.sigmoid))
            upsample = staticmethod(lambda t, s: tF.interpolate(t, scale_factor=s,
                                                                mode="nearest"))

        tparams = [(torch.tensor(w, requires_grad=True), torch.tensor(b, requires_grad=True))
                   for w, b in params]
        xt, gts = torch.tensor(x_np), [torch.tensor(g) for g in gs]

        def theirs_forward():
            return _dispnet_forward(xt, tparams, spec, Theirs, lambda xs: torch.cat(xs, 1),
                                    lambda t, th, tw: t[:, :, :th, :tw])

        def theirs_step():
            outs = theirs_forward()
            sum((o * g).sum() for o, g in zip(outs, gts)).backward()

        class TheirConvOnly(Theirs):
            elu = sigmoid = staticmethod(lambda t: t)

        fns.update(torch_fwd=_no_grad_torch(torch, theirs_forward), torch_fb=theirs_step,
                   torch_conv_only=_no_grad_torch(torch, lambda: _dispnet_forward(
                       xt, tparams, spec, TheirConvOnly, lambda xs: torch.cat(xs, 1),
                       lambda t, th, tw: t[:, :, :th, :tw])))
    row = dict(case=f"{variant} {size[0]}x{size[1]} b{batch}", **_measure(fns, repeat))
    flops = _conv_flops(x_np.shape, params, spec)
    row["conv_gflops"] = flops / row.pop("conv_only") / 1e6
    if "torch_conv_only" in row:
        row["torch_conv_gflops"] = flops / row.pop("torch_conv_only") / 1e6
    return row


# -- QNet conv stack + LSTM --------------------------------------------------------------
def bench_qnet(repeat, torch, np):
    from minid3rqn import autograd as ag
    from minid3rqn.autograd.conv import conv2d
    try:
        from minid3rqn.autograd.lstm import lstm
    except ImportError:
        lstm = None
    T, B, H, W, hidden = 5, 32, 32, 104, 256
    rng = np.random.default_rng(0)
    layers = [(1, 4, 4, 2), (4, 8, 4, 2), (8, 8, 3, 1)]          # (c_in, c_out, k, s)
    ws = [(rng.standard_normal((o, c, k, k)).astype(np.float32) * np.float32(0.3),
           np.zeros(o, np.float32), s) for c, o, k, s in layers]
    feat = 8 * 4 * 22
    w_ih = (rng.standard_normal((4 * hidden, feat)) * 0.03).astype(np.float32)
    w_hh = (rng.standard_normal((4 * hidden, hidden)) * 0.05).astype(np.float32)
    bias = np.zeros(4 * hidden, np.float32)
    frames = rng.random((T * B, 1, H, W), dtype=np.float32)
    g_out = rng.standard_normal((T, B, hidden) if lstm else (T * B, 8, 4, 22)).astype(np.float32)

    tw = [(ag.Tensor(w, requires_grad=True), ag.Tensor(b, requires_grad=True), s) for w, b, s in ws]
    lw = [ag.Tensor(a, requires_grad=True) for a in (w_ih, w_hh, bias)]
    x = ag.Tensor(frames)

    def ours_forward():
        h = x
        for w, b, s in tw:
            h = ag.relu(conv2d(h, w, b, s, 0))
        if lstm is None:
            return h
        return lstm(h.reshape(T, B, feat), None, None, *lw)[0]

    def ours_step():
        (ours_forward() * g_out).sum().backward()

    fns = {"ours_fwd": _no_grad_ours(ours_forward), "ours_fb": ours_step}
    if torch is not None:
        import torch.nn.functional as tF
        tws = [(torch.tensor(w, requires_grad=True), torch.tensor(b, requires_grad=True), s)
               for w, b, s in ws]
        net = torch.nn.LSTM(feat, hidden)
        with torch.no_grad():
            net.weight_ih_l0.copy_(torch.tensor(w_ih))
            net.weight_hh_l0.copy_(torch.tensor(w_hh))
            net.bias_ih_l0.zero_()
            net.bias_hh_l0.zero_()
        xt, gt = torch.tensor(frames), torch.tensor(g_out)

        def theirs_forward():
            h = xt
            for w, b, s in tws:
                h = tF.relu(tF.conv2d(h, w, b, s, 0))
            return net(h.reshape(T, B, feat))[0] if lstm is not None else h

        def theirs_step():
            (theirs_forward() * gt).sum().backward()

        fns.update(torch_fwd=_no_grad_torch(torch, theirs_forward), torch_fb=theirs_step)
    name = "qnet conv" + (" + lstm" if lstm else "") + f" {T}x{B} 32x104"
    return dict(case=name, **_measure(fns, repeat))


# -- bilinear sampling -------------------------------------------------------------------
def bench_sample(repeat, torch, np):
    from minid3rqn import autograd as ag
    try:
        from minid3rqn.autograd.sample import bilinear_sample
    except ImportError:
        return None
    N, C, H, W = 4, 3, 32, 104
    rng = np.random.default_rng(0)
    image = rng.random((N, C, H, W), dtype=np.float32)
    ys, xs = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    grid = np.stack([xs, ys], -1)[None].astype(np.float32)
    coords = (grid + rng.normal(0, 3, (N, H, W, 2))).astype(np.float32)
    g = rng.standard_normal((N, C, H, W)).astype(np.float32)
    img_t, crd_t = ag.Tensor(image, requires_grad=True), ag.Tensor(coords, requires_grad=True)

    def ours_forward():
        return bilinear_sample(img_t, crd_t, "zeros")[0]

    def ours_step():
        (ours_forward() * g).sum().backward()

    fns = {"ours_fwd": _no_grad_ours(ours_forward), "ours_fb": ours_step}
    if torch is not None:
        import torch.nn.functional as tF
        it = torch.tensor(image, requires_grad=True)
        ct = torch.tensor(coords, requires_grad=True)
        scale = torch.tensor([2.0 / (W - 1), 2.0 / (H - 1)])
        gt = torch.tensor(g)

        def theirs_forward():
            return tF.grid_sample(it, ct * scale - 1, mode="bilinear", padding_mode="zeros",
                                  align_corners=True)

        def theirs_step():
            (theirs_forward() * gt).sum().backward()

        fns.update(torch_fwd=_no_grad_torch(torch, theirs_forward), torch_fb=theirs_step)
    return dict(case=f"bilinear_sample {N}x{C}x{H}x{W}", **_measure(fns, repeat))


def bench_gemm(repeat, torch, np):
    n = 1024
    rng = np.random.default_rng(0)
    a = rng.standard_normal((n, n), dtype=np.float32)
    b = rng.standard_normal((n, n), dtype=np.float32)
    fns = {"numpy": lambda: a @ b}
    if torch is not None:
        at, bt = torch.tensor(a), torch.tensor(b)
        fns["torch"] = lambda: at @ bt
    best = _measure(fns, repeat)
    row = dict(case=f"matmul {n}^3 float32 (GFLOP/s)", gflops=2 * n ** 3 / best["numpy"] / 1e6)
    if torch is not None:
        row["torch_gflops"] = 2 * n ** 3 / best["torch"] / 1e6
    return row


# -- driver ------------------------------------------------------------------------------
def worker(threads: int, cases, repeat: int, clock: str) -> list[dict]:
    global CLOCK
    CLOCK = CLOCKS[clock]
    import numpy as np
    sys.path.insert(0, ROOT)
    torch = load_torch(threads)
    rows = []
    for case in cases:
        if case in ("dispnet", "dispnet-sfm"):
            for size in ((32, 104), (64, 208)):
                rows.append(bench_dispnet(case, size, 4, repeat, torch, np))
        elif case == "qnet":
            rows.append(bench_qnet(repeat, torch, np))
        elif case == "sample":
            rows.append(bench_sample(repeat, torch, np))
        elif case == "gemm":
            rows.append(bench_gemm(repeat, torch, np))
    for r in rows:
        if r is not None:
            r["threads"] = threads
    return [r for r in rows if r is not None]


def print_rows(rows, repeat: int, clock: str) -> None:
    lines = []
    for r in rows:
        if "gflops" in r:
            lines.append([r["case"], str(r["threads"]), "", "", "", "", "",
                          f"numpy {r['gflops']:.0f} GFLOP/s, torch "
                          f"{fmt(r.get('torch_gflops'), '.0f')} GFLOP/s"])
            continue
        ratio = r["ours_fb"] / r["torch_fb"] if "torch_fb" in r else None
        notes = ""
        if "conv_gflops" in r:
            notes = (f"conv fwd GFLOP/s: ours {r['conv_gflops']:.0f}, torch "
                     f"{fmt(r.get('torch_conv_gflops'), '.0f')}")
        lines.append([r["case"], str(r["threads"]), fmt(r["ours_fwd"], ".2f"),
                      fmt(r["ours_fb"], ".2f"), fmt(r.get("torch_fwd"), ".2f"),
                      fmt(r.get("torch_fb"), ".2f"), fmt(ratio, ".2f"), notes])
    print_table([("case", 34), ("thr", 3), ("ours fwd", 9), ("ours f+b", 9),
                 ("torch fwd", 9), ("torch f+b", 9), ("ratio", 6)], lines,
                f"times in ms ({clock} clock), best of {repeat} (ours and torch "
                f"alternating); ratio = ours / torch, forward + backward")


def main(argv=None) -> None:
    cases_over_threads(argv, __doc__, __file__, CASES, worker, print_rows,
                       "timed runs per measurement")


if __name__ == "__main__":
    main()
