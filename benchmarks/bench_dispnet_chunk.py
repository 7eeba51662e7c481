"""How many frames should the DispNet's inference path run at a time?

    python benchmarks/bench_dispnet_chunk.py                     # chunks 1,2,4,8,16,32,64
    python benchmarks/bench_dispnet_chunk.py --chunks 4,8,16 --frames 512 --repeat 7

``DispNetInference`` (nets/fast.py) runs a large batch ``chunk`` frames at a time
(default 8), so that its buffers (about 1 MB per frame at 32x104) stay in the CPU
caches. The best chunk depends on the caches of the machine; the evaluation of 2000
flights on predicted depth spends most of its time here, so this script measures it.

Measured: the shipped basic DispNet (``minid3rqn/models/depth_basic.npz``) on
``--frames`` RGB frames rendered in ``basic`` worlds (uint8, as the flight loop gives
them), one thread (the evaluation runs one process per core), median of ``--repeat``
runs after three warm-ups (``bench_depth._median_ms``). For each chunk it also reports
the largest difference from the chunk-8 output: 0.0 means the chunk changes only the
speed, not a single bit of any evaluation (a GEMM may round differently when its row
count changes; if it does, changing the default would change every predicted depth).

On a 2-core AMD EPYC, chunks of 2 to 64 run within a few percent of each other, and
not to the bit, so the default stays 8.

``--elu`` instead times where a frame's time goes: the DispNet
in chunks of 8 with its in-place bias + ELU as shipped (``exp(x) - 1``), as it was
before (``expm1``, the arithmetic of ``ag.elu``), and replaced by a no-op (what is left:
the convolutions and the copies between layers; the outputs are then wrong, only the
time means something); and ``np.expm1`` against ``np.exp`` per float32 element, on an
array the size of the DispNet's largest layer for 8 frames.

    python benchmarks/bench_dispnet_chunk.py --elu

``--layers`` times each convolution of the DispNet (chunks of
8, as shipped) and reports its ms per frame and the GFLOP/s its GEMMs reach, beside the
ceiling (``bench_autograd``'s 1024^3 float32 ``np.matmul``, best of ``--repeat``, same
thread), then the time in the bias + ELU and in everything else (the copies between
layers, the sigmoid). It answers how much
faster the DispNet, which is most of an evaluation on predicted depth, could still get.

    python benchmarks/bench_dispnet_chunk.py --layers

Output: one JSON line per chunk (or per ELU variant, or per convolution), then one with
the machine's caches.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")          # before NumPy loads (one core per process)

import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from bench_autograd import bench_gemm  # noqa: E402  (this folder is on sys.path)
from bench_depth import _median_ms  # noqa: E402
from minid3rqn.depth.evaluate import DepthEstimator  # noqa: E402
from minid3rqn.nets import fast as nets_fast  # noqa: E402
from minid3rqn.nets.fast import DispNetInference  # noqa: E402
from minid3rqn.world import Camera, SceneBatch, make_scene, render_batch, sample_start_pose  # noqa: E402

MODEL = os.path.join(ROOT, "minid3rqn", "models", "depth_basic.npz")


def rendered_frames(n: int, seed: int = 0) -> np.ndarray:
    """``n`` uint8 RGB frames (n, H, W, 3) from random free poses in ``basic`` worlds."""
    rng = np.random.default_rng(seed)
    scenes = [make_scene("basic", 1_000_000 + k) for k in range(8)]
    pick = rng.integers(0, len(scenes), n)
    poses = np.array([sample_start_pose(scenes[k], rng) for k in pick])
    rgb, _ = render_batch(SceneBatch([scenes[k] for k in pick]), poses, Camera())
    return np.ascontiguousarray(rgb)


def caches() -> dict:
    """The CPU's cache sizes as Linux reports them (empty elsewhere)."""
    out = {}
    base = "/sys/devices/system/cpu/cpu0/cache"
    try:
        for d in sorted(os.listdir(base)):
            if not d.startswith("index"):
                continue
            with open(os.path.join(base, d, "level")) as f:
                level = f.read().strip()
            with open(os.path.join(base, d, "type")) as f:
                kind = f.read().strip()
            with open(os.path.join(base, d, "size")) as f:
                out[f"L{level}{'' if kind == 'Unified' else kind[0].lower()}"] = f.read().strip()
    except OSError:
        pass
    return out


def _elu_expm1_(y, bias, scratch, zeros):
    """The inference ELU computed with ``expm1`` (``ag.elu``'s arithmetic to the
    bit), for comparison with the shipped ``exp(x) - 1``."""
    if bias is not None:
        y += bias
    np.minimum(y, zeros, out=scratch)
    np.maximum(y, zeros, out=y)
    np.expm1(scratch, out=scratch)
    y += scratch
    return y


def _no_elu_(y, bias, scratch, zeros):
    return y


def bench_elu(est: DepthEstimator, rgb: np.ndarray, repeat: int) -> None:
    """Print the ms per frame of the DispNet with each ELU variant, and the ns per
    element of ``np.expm1`` and ``np.exp`` (see the module docstring)."""
    shipped = nets_fast.bias_elu_
    variants = {"exp (shipped)": shipped, "expm1 (before)": _elu_expm1_, "none": _no_elu_}
    try:
        for name, fn in variants.items():
            nets_fast.bias_elu_ = fn        # read by every layer at call time
            fast = DispNetInference(est.net, chunk=8)
            ms = _median_ms(lambda: fast(rgb), repeat)
            print(json.dumps({"elu": name, "frames": len(rgb),
                              "ms_per_frame": round(ms / len(rgb), 3)}), flush=True)
    finally:
        nets_fast.bias_elu_ = shipped
    x = -np.random.default_rng(0).random(8 * 32 * 104 * 16).astype(np.float32)
    out = np.empty_like(x)
    for name, ufunc in (("expm1", np.expm1), ("exp", np.exp)):
        ms = _median_ms(lambda: ufunc(x, out=out), 20 * repeat)
        print(json.dumps({"ufunc": name, "elements": x.size,
                          "ns_per_element": round(1e6 * ms / x.size, 2)}), flush=True)


def bench_layers(est: DepthEstimator, rgb: np.ndarray, repeat: int) -> None:
    """Print, per convolution of the DispNet (chunks of 8), its ms per frame and GFLOP/s;
    then the bias + ELU, the rest, and the GEMM ceiling (see the module docstring).

    Each bound convolution and the in-place bias + ELU are wrapped with a timer; the
    wrappers cost a few microseconds per call, so the total is a little above an
    unwrapped run's (also printed)."""
    plain = DispNetInference(est.net, chunk=8)
    plain_ms = _median_ms(lambda: plain(rgb), repeat)
    timers: dict = {}       # conv index -> [seconds, calls, flops per call, in, out, kernel, stride]
    elu = [0.0]
    bind, shipped = nets_fast.ConvInference.bind, nets_fast.bias_elu_

    def timed_bind(self, xp, out, work):
        run = bind(self, xp, out, work)
        kh, kw = self.kernel
        flops = 2 * out.size * xp.shape[3] * kh * kw      # out is (n, OH, OW, O)
        entry = timers.setdefault(len(timers), [0.0, 0, flops, xp.shape[1:], out.shape[1:],
                                                (kh, kw), self.stride])

        def timed():
            t = time.perf_counter()
            run()
            entry[0] += time.perf_counter() - t
            entry[1] += 1
        return timed

    def timed_elu(*args):
        t = time.perf_counter()
        y = shipped(*args)
        elu[0] += time.perf_counter() - t
        return y

    try:
        nets_fast.ConvInference.bind, nets_fast.bias_elu_ = timed_bind, timed_elu
        fast = DispNetInference(est.net, chunk=8)
        for _ in range(3):                  # warm-up: builds the workspace, binds
            fast(rgb)
        for entry in timers.values():
            entry[0], entry[1] = 0.0, 0
        elu[0] = 0.0
        t = time.perf_counter()
        for _ in range(repeat):
            fast(rgb)
        total = time.perf_counter() - t
    finally:
        nets_fast.ConvInference.bind, nets_fast.bias_elu_ = bind, shipped
    frames = repeat * len(rgb)
    for k, (sec, calls, flops, xin, yout, kern, stride) in timers.items():
        print(json.dumps({"conv": k, "in_hwc": list(xin), "out_hwc": list(yout),
                          "kernel": list(kern), "stride": list(stride),
                          "ms_per_frame": round(1000 * sec / frames, 4),
                          "gflops": round(flops * calls / sec / 1e9, 1)}), flush=True)
    conv = sum(e[0] for e in timers.values())
    print(json.dumps({"ms_per_frame": {"total (timed)": round(1000 * total / frames, 3),
                                       "total (untimed run)": round(plain_ms / len(rgb), 3),
                                       "convolutions": round(1000 * conv / frames, 3),
                                       "bias + ELU": round(1000 * elu[0] / frames, 3),
                                       "rest": round(1000 * (total - conv - elu[0]) / frames, 3)},
                      "gemm_ceiling_gflops": round(bench_gemm(repeat, None, np)["gflops"], 1)}),
          flush=True)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--chunks", default="1,2,4,8,16,32,64",
                   help="comma-separated chunk sizes to time")
    p.add_argument("--frames", type=int, default=512, help="frames per timed call")
    p.add_argument("--repeat", type=int, default=5)
    what = p.add_mutually_exclusive_group()
    what.add_argument("--elu", action="store_true",
                      help="time the ELU variants and expm1 against exp instead of the chunks")
    what.add_argument("--layers", action="store_true",
                      help="time each convolution (ms per frame, GFLOP/s) instead of the chunks")
    args = p.parse_args()
    try:
        chunks = [int(c) for c in args.chunks.split(",")]
    except ValueError:
        p.error(f"--chunks must be comma-separated integers; got {args.chunks!r}")
    if min(chunks) < 1 or args.frames < 1 or args.repeat < 1:
        p.error("--chunks, --frames and --repeat must be >= 1")

    est = DepthEstimator.load(MODEL)
    rgb = rendered_frames(args.frames)
    if args.elu or args.layers:
        (bench_elu if args.elu else bench_layers)(est, rgb, args.repeat)
        print(json.dumps({"caches": caches(), "threads": os.environ.get("OMP_NUM_THREADS")}))
        return 0
    reference = DispNetInference(est.net, chunk=8)(rgb)
    for chunk in chunks:
        fast = DispNetInference(est.net, chunk=chunk)
        out = fast(rgb)
        diff = float(np.max(np.abs(out.astype(np.float64) - reference)))
        ms = _median_ms(lambda: fast(rgb), args.repeat)
        print(json.dumps({"chunk": chunk, "frames": args.frames,
                          "ms_per_frame": round(ms / args.frames, 3),
                          "frames_per_s": round(1000 * args.frames / ms, 1),
                          "max_abs_diff_vs_chunk8": diff}), flush=True)
    print(json.dumps({"caches": caches(), "threads": os.environ.get("OMP_NUM_THREADS")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
