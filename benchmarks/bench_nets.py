"""The project's networks against the same networks in PyTorch, at the shipped shapes.

    python benchmarks/bench_nets.py                      # 1 and 2 threads, every case
    python benchmarks/bench_nets.py --threads 1 --repeat 30 --clock cpu
    python benchmarks/bench_nets.py --cases act,depth

Every case runs our class itself (``QNet``, ``DispNet``, ``Agent.update``) and a torch
module holding the same weights (copied from ours; the outputs are checked to agree
before anything is timed). Times are medians over ``--repeat`` runs after warm-ups,
ours and torch alternating, so load from other processes hits both alike; ``ratio`` is
ours / torch (below 1: we are faster). For each thread count the script re-runs
itself in a child with OMP/OPENBLAS/MKL_NUM_THREADS set before NumPy loads, and
``torch.set_num_threads`` set to the same number. ``--clock cpu`` times the process's
CPU time (one thread only: preemption by other processes no longer counts).

Cases (float32; the shipped models' weights when present, else the default
architecture, same speed):

- ``act``: ``QNet.step`` under ``no_grad``, batch 1 and 16, with a carried LSTM state
  (acting: ``Agent.act``, ``QNetPolicy.act``, ``fly``, ``evaluate``).
- ``depth``: ``DispNet.forward(x, scales=1)`` under ``no_grad``, 32x104, batch 1 and 16
  (what ``DepthEstimator.predict`` runs).
- ``train``: forward + backward of the DispNet (4 scales, batch 4, 32x104 and 64x208;
  the gradient of sum_i <disp_i, g_i>) and of the Q-net over a T = 6, B = 32 window;
  and the whole D3RQN update (``benchmarks/bench_rl.py``'s ``update`` part: online and
  target nets, double-Q targets, Huber, backward, clipping, Adam).
- ``conv``: the convolutions of the DispNet forward at batch 16 under ``no_grad``, one
  layer after another, in GFLOP/s (2 x multiply-adds / time), beside a 1024^3 float32
  ``np.matmul`` (NumPy's own GEMM rate on this machine) and torch's ``conv2d``.
"""
from __future__ import annotations

import os
import sys
import time

from _timing import CLOCKS, cases_over_threads, fmt, load_torch, measure, print_table

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CASES = ("act", "depth", "train", "conv")
CLOCK = time.perf_counter          # --clock cpu: time.process_time


def _measure(fns: dict, repeat: int) -> dict:
    """Median ms of each callable over ``repeat`` rounds, the callables alternating,
    after 3 warm-ups (benchmarks/_timing.py)."""
    return measure(fns, repeat, warmup=3, clock=CLOCK)


def _row(case: str, ours: float, theirs: float | None, **extra) -> dict:
    return dict(case=case, ours_ms=ours, torch_ms=theirs,
                ratio=None if theirs is None else ours / theirs, **extra)


# -- the networks, ours and torch's ------------------------------------------------------
def _shipped_qnet():
    from minid3rqn.nets.qnet import QNet, QNetConfig
    from minid3rqn.rl.models import SHIPPED_QNET
    from minid3rqn.rl.policies import QNetPolicy
    if SHIPPED_QNET.exists():
        return QNetPolicy.load(SHIPPED_QNET, "D3RQN").qnet
    return QNet(QNetConfig(), rng=0)


def _shipped_dispnet():
    from minid3rqn.depth.evaluate import DepthEstimator
    from minid3rqn.nets.dispnet import DispNet
    from minid3rqn.rl.models import shipped_depth_model
    path = shipped_depth_model("basic")
    return DepthEstimator.load(path).net if path.exists() else DispNet()


def _torch_dispnet(net, torch):
    """``nets/dispnet.py``'s DispNet in torch, with ``net``'s weights."""
    nn, F = torch.nn, torch.nn.functional

    class DispNetT(nn.Module):
        def __init__(self):
            super().__init__()
            conv = lambda ci, co, s=1: nn.Conv2d(ci, co, 3, s, 1)      # noqa: E731
            e, d = net.encoder_channels, net.decoder_channels
            self.enc_a = nn.ModuleList([conv(a, b, 2) for a, b in zip((3,) + e[:-1], e)])
            self.enc_b = nn.ModuleList([conv(c, c) for c in e])
            ins = [e[-1]] + [d[i] for i in reversed(range(1, len(e)))]
            self.dec_a = nn.ModuleList([conv(c, d[i]) for c, i in
                                        zip(ins, reversed(range(len(e))))])
            self.dec_b = nn.ModuleList([conv(d[i] + (e[i - 1] if i else 0), d[i])
                                        for i in reversed(range(len(e)))])
            self.heads = nn.ModuleList([conv(d[i], 1) for i in range(net.n_scales)])

        def forward(self, x, scales=None):
            h, w = x.shape[2:]
            x = (x - 0.45) / 0.225
            feats = []
            for a, b in zip(self.enc_a, self.enc_b):
                x = F.elu(b(F.elu(a(x))))
                feats.append(x)
            n_out = net.n_scales if scales is None else scales
            out = [None] * net.n_scales
            for j, i in enumerate(reversed(range(len(feats)))):
                x = F.interpolate(F.elu(self.dec_a[j](x)), scale_factor=2, mode="nearest")
                x = x[:, :, :-(-h // 2 ** i), :-(-w // 2 ** i)]
                if i > 0:
                    x = torch.cat([x, feats[i - 1]], 1)
                x = F.elu(self.dec_b[j](x))
                if i < n_out:
                    out[i] = torch.sigmoid(self.heads[i](x)) * net.disp_scale + net.min_disp
            return out[:n_out]

    t = DispNetT()
    t.load_state_dict({k: torch.from_numpy(v) for k, v in net.state_dict().items()})
    return t


def _torch_qnet(net, torch):
    sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
    from bench_rl import _torch_qnet as build
    return build(net, torch)


def _check(ours, theirs, what: str, rtol: float = 1e-4) -> None:
    import numpy as np
    scale = max(1.0, float(np.max(np.abs(theirs))))
    err = float(np.max(np.abs(ours - theirs)))
    if err > rtol * scale:
        raise AssertionError(f"bench_nets: {what}: ours and torch differ by {err:.3g}")


# -- cases ---------------------------------------------------------------------------------
def bench_act(repeat, torch, np, ag):
    net = _shipped_qnet()
    tq = None if torch is None else _torch_qnet(net, torch)
    rows, rng = [], np.random.default_rng(0)
    cfg = net.config
    for batch in (1, 16):
        obs = rng.random((batch, cfg.in_channels, cfg.height, cfg.width_px)).astype(np.float32)
        h = rng.normal(scale=0.3, size=(batch, cfg.width)).astype(np.float32)
        c = rng.normal(scale=0.3, size=(batch, cfg.width)).astype(np.float32)
        state = (ag.Tensor(h), ag.Tensor(c))

        def ours():
            with ag.no_grad():
                return net.step(obs, state)[0].data
        fns = {"ours": ours}
        if tq is not None:
            obs_t, hc_t = torch.from_numpy(obs), (torch.from_numpy(h)[None],
                                                  torch.from_numpy(c)[None])

            def theirs():
                with torch.no_grad():
                    z = obs_t
                    for conv in tq.convs:
                        z = torch.relu(conv(z))
                    z, _ = tq.lstm(z.reshape(1, batch, -1), hc_t)
                    a = tq.adv(z)
                    return (tq.value(z) + a - a.mean(-1, keepdim=True))[0]
            _check(ours(), theirs().numpy(), f"QNet.step batch {batch}")
            fns["torch"] = theirs
        t = _measure(fns, 20 * repeat)
        rows.append(_row(f"act: QNet.step b{batch}", t["ours"], t.get("torch")))
    return rows


def bench_depth(repeat, torch, np, ag):
    net = _shipped_dispnet()
    tn = None if torch is None else _torch_dispnet(net, torch)
    rows, rng = [], np.random.default_rng(0)
    for batch in (1, 16):
        x = np.ascontiguousarray(rng.random((batch, 32, 104, 3), dtype=np.float32))
        x = x.transpose(0, 3, 1, 2)                      # channels-last, as predict's

        def ours():
            with ag.no_grad():
                return net(x, scales=1)[0].data
        fns = {"ours": ours}
        if tn is not None:
            xt = torch.from_numpy(np.ascontiguousarray(x))

            def theirs():
                with torch.no_grad():
                    return tn(xt, scales=1)[0]
            _check(ours(), theirs().numpy(), f"DispNet batch {batch}")
            fns["torch"] = theirs
        t = _measure(fns, (10 if batch == 1 else 2) * repeat)
        rows.append(_row(f"depth: DispNet.forward b{batch} 32x104", t["ours"], t.get("torch")))
    return rows


def bench_train(repeat, torch, np, ag, threads):
    rows, rng = [], np.random.default_rng(0)
    net = _shipped_dispnet()
    tn = None if torch is None else _torch_dispnet(net, torch)
    for size in ((32, 104), (64, 208)):
        x = rng.random((4, 3) + size, dtype=np.float32)
        gs = [rng.standard_normal((4, 1, -(-size[0] // 2 ** i), -(-size[1] // 2 ** i)))
              .astype(np.float32) for i in range(net.n_scales)]

        def ours():
            net.zero_grad()
            outs = net(x)
            loss = (outs[0] * gs[0]).sum()
            for o, g in zip(outs[1:], gs[1:]):
                loss = loss + (o * g).sum()
            loss.backward()
        fns = {"ours": ours}
        if tn is not None:
            xt, gts = torch.from_numpy(x), [torch.from_numpy(g) for g in gs]

            def theirs():
                tn.zero_grad()
                sum((o * g).sum() for o, g in zip(tn(xt), gts)).backward()
            fns["torch"] = theirs
        t = _measure(fns, repeat)
        rows.append(_row(f"train: DispNet f+b b4 {size[0]}x{size[1]}", t["ours"],
                         t.get("torch")))

    q = _shipped_qnet()
    T, B = 6, 32
    obs = rng.random((T, B, 1, 32, 104)).astype(np.float32)
    g = rng.standard_normal((T, B, q.config.n_actions)).astype(np.float32)

    def ours_q():
        q.zero_grad()
        (q(obs)[0] * g).sum().backward()
    fns = {"ours": ours_q}
    if torch is not None:
        tq = _torch_qnet(q, torch)
        obs_t, g_t = torch.from_numpy(obs), torch.from_numpy(g)

        def theirs_q():
            tq.zero_grad()
            (tq(obs_t) * g_t).sum().backward()
        with ag.no_grad():
            _check(q(obs)[0].data, tq(obs_t).detach().numpy(), "QNet over T=6 B=32")
        fns["torch"] = theirs_q
    t = _measure(fns, repeat)
    rows.append(_row(f"train: QNet f+b T={T} B={B}", t["ours"], t.get("torch")))

    sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
    from bench_rl import bench_update
    up = bench_update(repeat, threads, clock=CLOCK)
    rows.append(_row("train: D3RQN update 32x5", up["ours_ms"], up.get("torch_ms")))
    return rows


def bench_conv(repeat, torch, np, ag):
    """The DispNet's convolutions at batch 16, no graph: total GFLOP/s, and NumPy's GEMM."""
    from minid3rqn.autograd.conv import conv2d
    net = _shipped_dispnet()
    rng = np.random.default_rng(0)
    layers, flops = [], 0
    h, w = 32, 104
    shapes = []                                     # (conv, input h, w) in forward order
    for a, b in zip(net.enc_a, net.enc_b):
        shapes += [(a, h, w), (b, -(-h // 2), -(-w // 2))]
        h, w = -(-h // 2), -(-w // 2)
    for j, i in enumerate(reversed(range(len(net.enc_a)))):
        shapes += [(net.dec_a[j], h, w)]
        h, w = -(-32 // 2 ** i), -(-104 // 2 ** i)
        shapes += [(net.dec_b[j], h, w)]
    shapes += [(net.heads[0], 32, 104)]
    for conv, hh, ww in shapes:
        O, C, KH, KW = conv.weight.shape
        x = np.ascontiguousarray(rng.random((16, hh, ww, C), dtype=np.float32))
        x = x.transpose(0, 3, 1, 2)
        oh = (hh + 2 * conv.padding[0] - KH) // conv.stride[0] + 1
        ow = (ww + 2 * conv.padding[1] - KW) // conv.stride[1] + 1
        flops += 2 * 16 * oh * ow * O * C * KH * KW
        layers.append((conv, x))

    def ours():
        with ag.no_grad():
            for conv, x in layers:
                conv2d(x, conv.weight, conv.bias, conv.stride, conv.padding)
    n = 1024
    a = rng.standard_normal((n, n), dtype=np.float32)
    fns = {"ours": ours, "gemm": lambda: a @ a}
    if torch is not None:
        tl = [(torch.from_numpy(np.ascontiguousarray(x)), torch.from_numpy(c.weight.data),
               torch.from_numpy(c.bias.data), c.stride, c.padding) for c, x in layers]

        def theirs():
            with torch.no_grad():
                for x, wt, b, s, p in tl:
                    torch.nn.functional.conv2d(x, wt, b, s, p)
        fns["torch"] = theirs
    t = _measure(fns, 2 * repeat)
    gemm = 2 * n ** 3 / t["gemm"] / 1e6
    ours_gf = flops / t["ours"] / 1e6
    row = _row("conv: DispNet convs b16, GFLOP/s", t["ours"], t.get("torch"),
               ours_gflops=ours_gf, gemm_gflops=gemm, share_of_gemm=ours_gf / gemm)
    if torch is not None:
        row["torch_gflops"] = flops / t["torch"] / 1e6
    return [row]


# -- driver ------------------------------------------------------------------------------
def worker(threads: int, cases, repeat: int, clock: str) -> list[dict]:
    global CLOCK
    CLOCK = CLOCKS[clock]
    import numpy as np
    sys.path.insert(0, ROOT)
    from minid3rqn import autograd as ag
    from minid3rqn.allocator import keep_freed_memory
    keep_freed_memory()                     # as python -m minid3rqn does
    torch = load_torch(threads)
    rows = []
    for case in cases:
        if case == "act":
            rows += bench_act(repeat, torch, np, ag)
        elif case == "depth":
            rows += bench_depth(repeat, torch, np, ag)
        elif case == "train":
            rows += bench_train(repeat, torch, np, ag, threads)
        elif case == "conv":
            rows += bench_conv(repeat, torch, np, ag)
    for r in rows:
        r["threads"] = threads
    return rows


def print_rows(rows, repeat: int, clock: str) -> None:
    lines = []
    for r in rows:
        notes = ""
        if "ours_gflops" in r:
            notes = (f"ours {r['ours_gflops']:.0f} GFLOP/s = {100 * r['share_of_gemm']:.0f}% "
                     f"of NumPy's GEMM ({r['gemm_gflops']:.0f}); torch "
                     f"{r.get('torch_gflops', float('nan')):.0f}")
        lines.append([r["case"], str(r["threads"]), fmt(r["ours_ms"], ".3f"),
                      fmt(r["torch_ms"], ".3f"), fmt(r["ratio"], ".3f"), notes])
    print_table([("case", 38), ("thr", 3), ("ours ms", 9), ("torch ms", 9), ("ratio", 6)],
                lines, f"medians of {repeat}+ runs ({clock} clock), ours and torch "
                       f"alternating; ratio = ours / torch")


def main(argv=None) -> None:
    cases_over_threads(argv, __doc__, __file__, CASES, worker, print_rows,
                       "timed runs per case", json_option=True)


if __name__ == "__main__":
    main()
