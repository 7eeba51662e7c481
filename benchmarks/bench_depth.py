"""Speed of depth training and inference, ours against the same networks in PyTorch.

    python benchmarks/bench_depth.py                 # 1 and 2 threads
    python benchmarks/bench_depth.py --threads 1 --repeat 20

Measured (medians over ``--repeat`` runs after 3 warm-ups, float32, 32x104):

- ``train_iter``: one whole training iteration, as ``depth/train.py`` runs it with the
  default config: DispNet on 4 targets (4 scales), PoseNet on 4 triplets, the
  view-synthesis loss (2 sources warped at 4 scales on downsampled images, SSIM,
  min-reprojection, auto-masking, edge-aware smoothness, known-speed term), backward,
  Adam step. The torch side mirrors every step (the DispNet of ``bench_nets.py``,
  ``grid_sample`` with align_corners=True for our sampler, ``avg_pool2d`` for our area
  downsampling) and starts from OUR weights, so the two losses must agree: the script
  checks it before timing.
- ``infer_fps``: DispNet (finest scale only) on batches of 64 uint8 frames, no graph,
  through ``DepthEstimator.predict_disp`` (``DispNet.forward`` under ``no_grad``, 32
  frames at a time). ``infer_ms_b1``: one frame (batch 1, the flight loop). The script
  checks that it agrees with the forward that records the graph (1e-4 relative).

For each thread count the script re-runs itself in a child process with
OMP_NUM_THREADS / OPENBLAS_NUM_THREADS / MKL_NUM_THREADS set before NumPy loads, and
``torch.set_num_threads`` set to the same number. Output: one JSON line per count.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

from _timing import load_torch, median_ms, positive_int, run_child, thread_counts
from bench_nets import _torch_dispnet

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _child(threads: int, repeat: int) -> dict:
    import numpy as np
    sys.path.insert(0, ROOT)
    from minid3rqn import autograd as ag
    from minid3rqn.autograd.optim import Adam
    from minid3rqn.depth.losses import view_synthesis_loss
    from minid3rqn.depth.train import TrainConfig, build_nets
    from minid3rqn.world import Camera

    cfg = TrainConfig()
    K = Camera().K
    rng = np.random.default_rng(0)
    n, h, w = 4, 32, 104
    # Smooth random images (so the warp and SSIM see structure, as with real frames).
    base = rng.random((n, 3, h // 4, w // 4)).astype(np.float32)
    target = base.repeat(4, 2).repeat(4, 3)
    sources = [np.roll(target, k, axis=3) for k in (-1, 1)]
    disp, pose = build_nets(cfg)
    params = disp.parameters() + pose.parameters()
    opt = Adam(params, lr=cfg.lr)

    def ours_iter():
        disps = disp(target)
        poses = pose(target, sources)
        loss, _ = view_synthesis_loss(target, sources, disps, poses, K, cfg.loss)
        opt.zero_grad()
        loss.backward()
        opt.step()
        return float(loss.data)

    frames = rng.random((64, 3, h, w)).astype(np.float32)
    frames_u8 = (frames.transpose(0, 2, 3, 1) * 255).astype(np.uint8)
    frames_in = frames_u8.transpose(0, 3, 1, 2).astype(np.float32) * np.float32(1 / 255)

    from minid3rqn.depth.evaluate import DepthEstimator
    from minid3rqn.depth.flip import FlipAveraged
    est = DepthEstimator(disp, 1.0, {"height": h, "width": w})
    flip_est = FlipAveraged(DepthEstimator(disp, 1.0, {"height": h, "width": w}))

    def ours_infer():
        est.predict_disp(frames_u8)

    def ours_infer_b1():
        est.predict_disp(frames_u8[:1])

    def ours_infer_flip():                  # test-time flip: the frame and its mirror
        flip_est.predict_disp(frames_u8)

    ref = disp(frames_in, scales=1)[0].data[:, 0]           # the graph on
    rel = float(np.max(np.abs(est.predict_disp(frames_u8) - ref) / ref))
    if rel > 1e-4:
        raise AssertionError(f"bench_depth: predict_disp differs from the forward with "
                             f"the graph by {rel:.2g} (relative)")

    result = {"threads": threads}
    torch_side = _torch_side(disp, pose, target, sources, K, cfg, frames, threads)
    if torch_side is not None:
        # Same weights, same batch: the losses must agree before anything is timed.
        with ag.no_grad():
            ours_loss = float(view_synthesis_loss(target, sources, disp(target),
                                                  pose(target, sources), K, cfg.loss)[0].data)
        result["loss_ours"], result["loss_torch"] = ours_loss, torch_side["loss"]()
        if abs(ours_loss - result["loss_torch"]) > 1e-4 * max(1.0, abs(ours_loss)):
            raise AssertionError(f"bench_depth: losses differ: ours {ours_loss}, torch "
                                 f"{result['loss_torch']}")
    result["infer_max_rel_diff"] = rel
    result["infer_fps_ours"] = 64 / (median_ms(ours_infer, repeat) / 1000)
    result["infer_fps_ours_flip"] = 64 / (median_ms(ours_infer_flip, repeat) / 1000)
    result["infer_ms_b1_ours"] = median_ms(ours_infer_b1, 20 * repeat)
    result["train_iter_ms_ours"] = median_ms(ours_iter, repeat)
    if torch_side is not None:
        result["train_iter_ms_torch"] = median_ms(torch_side["iter"], repeat)
        result["infer_fps_torch"] = 64 / (median_ms(torch_side["infer"], repeat) / 1000)
        result["infer_ms_b1_torch"] = median_ms(torch_side["infer_b1"], 20 * repeat)
        result["train_ratio"] = result["train_iter_ms_ours"] / result["train_iter_ms_torch"]
    return result


def _torch_side(disp, pose, target, sources, K, cfg, frames, threads):
    torch = load_torch(threads)
    if torch is None:
        return None
    import numpy as np
    from minid3rqn.depth.losses import SMOOTH_WEIGHT, SPEED_WEIGHT, STEP
    nn, F = torch.nn, torch.nn.functional

    class PoseNetT(nn.Module):
        def __init__(self):
            super().__init__()
            ch = (9,) + pose.channels
            self.convs = nn.ModuleList([nn.Conv2d(a, b, 3, 2, 1) for a, b in zip(ch, ch[1:])])
            self.head = nn.Conv2d(ch[-1], 12, 1)

        def forward(self, t, s):
            x = (torch.cat([t] + s, 1) - 0.45) / 0.225
            for c in self.convs:
                x = F.relu(c(x))
            return (self.head(x).mean((2, 3)) * pose.pose_scale).view(-1, 2, 6)

    dn, pn = _torch_dispnet(disp, torch), PoseNetT()
    pn.load_state_dict({k: torch.from_numpy(v) for k, v in pose.state_dict().items()})
    Kt = torch.tensor(K, dtype=torch.float32)
    tgt = torch.from_numpy(target)
    srcs = [torch.from_numpy(np.ascontiguousarray(s)) for s in sources]
    lc = cfg.loss
    n, _, h, w = target.shape

    def euler(a):
        cx, sx = torch.cos(a[:, 0]), torch.sin(a[:, 0])
        cy, sy = torch.cos(a[:, 1]), torch.sin(a[:, 1])
        cz, sz = torch.cos(a[:, 2]), torch.sin(a[:, 2])
        return torch.stack([torch.stack([cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx], 1),
                            torch.stack([sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx], 1),
                            torch.stack([-sy, cy * sx, cy * cx], 1)], 1)

    def scaled_k(f):
        k = Kt.clone()
        k[0, 0] /= f
        k[1, 1] /= f
        k[0, 2] = (k[0, 2] + 0.5) / f - 0.5
        k[1, 2] = (k[1, 2] + 0.5) / f - 0.5
        return k

    def box3(x):
        return F.avg_pool2d(F.pad(x, (1, 1, 1, 1), mode="replicate"), 3, 1)

    def dssim(x, y):
        mx, my = box3(x), box3(y)
        sx, sy, sxy = box3(x * x) - mx * mx, box3(y * y) - my * my, box3(x * y) - mx * my
        num = (2 * mx * my + 1e-4) * (2 * sxy + 9e-4)
        den = (mx * mx + my * my + 1e-4) * (sx + sy + 9e-4)
        return torch.clamp((1 - num / den) / 2, 0, 1)

    def pe(a, b):
        l1 = (a - b).abs().mean(1, keepdim=True)
        return lc.ssim_weight * dssim(a, b).mean(1, keepdim=True) + (1 - lc.ssim_weight) * l1

    def photo_term(tg, ss, depth, R, t, k):
        S, (hh, ww) = len(ss), tg.shape[2:]
        v, u = torch.meshgrid(torch.arange(hh, dtype=torch.float32),
                              torch.arange(ww, dtype=torch.float32), indexing="ij")
        rays = torch.linalg.inv(k) @ torch.stack([u.ravel(), v.ravel(), torch.ones(hh * ww)])
        pts = depth.repeat(S, 1, 1, 1).view(-1, 1, hh * ww) * rays
        proj = (k @ R) @ pts + k @ t
        z = proj[:, 2]
        x, y = proj[:, 0] / z.clamp(min=1e-3), proj[:, 1] / z.clamp(min=1e-3)
        valid = ((x >= 0) & (x <= ww - 1) & (y >= 0) & (y <= hh - 1) & (z > 1e-3)
                 & (depth.repeat(S, 1, 1, 1).view(-1, hh * ww) > 0)).float()
        grid = torch.stack([2 * x / (ww - 1) - 1, 2 * y / (hh - 1) - 1], -1).view(-1, hh, ww, 2)
        warped = F.grid_sample(torch.cat(ss), grid, padding_mode="border", align_corners=True)
        err = pe(warped, tg.repeat(S, 1, 1, 1)).view(S, n, 1, hh, ww)
        best = (err + 1e3 * (1 - valid.view(S, n, 1, hh, ww))).min(0).values
        with torch.no_grad():
            idn = pe(torch.cat(ss), tg.repeat(S, 1, 1, 1)).view(S, n, 1, hh, ww).min(0).values
        return torch.minimum(best, idn).mean()

    def loss_fn(disps, poses):
        p = poses.transpose(0, 1).reshape(-1, 6)
        R, t = euler(p[:, 3:]), p[:, :3, None]
        photo, smooth = 0, 0
        for i, d in enumerate(disps):
            f = 2 ** i
            tg = F.avg_pool2d(tgt, f) if i else tgt
            ss = [F.avg_pool2d(x, f) if i else x for x in srcs]
            photo = photo + photo_term(tg, ss, 1 / d, R, t, scaled_k(f))
            dn_ = d / (d.mean((2, 3), keepdim=True) + 1e-7)
            dx = (dn_[..., 1:] - dn_[..., :-1]).abs() * torch.exp(
                -(tg[..., 1:] - tg[..., :-1]).abs().mean(1, keepdim=True))
            dy = (dn_[..., 1:, :] - dn_[..., :-1, :]).abs() * torch.exp(
                -(tg[..., 1:, :] - tg[..., :-1, :]).abs().mean(1, keepdim=True))
            smooth = smooth + (dx.mean() + dy.mean()) / f
        n_sc = len(disps)
        speed = ((poses[..., :3] ** 2).sum(-1) + 1e-12).sqrt().sub(STEP).abs().mean()
        return photo / n_sc + SMOOTH_WEIGHT * smooth / n_sc + SPEED_WEIGHT * speed

    opt = torch.optim.Adam(list(dn.parameters()) + list(pn.parameters()), lr=cfg.lr)
    fr = torch.from_numpy(frames)

    def loss_value():
        with torch.no_grad():
            return float(loss_fn(dn(tgt), pn(tgt, srcs)))

    def one_iter():
        loss = loss_fn(dn(tgt), pn(tgt, srcs))
        opt.zero_grad()
        loss.backward()
        opt.step()

    def infer():
        with torch.no_grad():
            dn(fr, scales=1)

    fr1 = fr[:1].clone()

    def infer_b1():
        with torch.no_grad():
            dn(fr1, scales=1)

    return {"loss": loss_value, "iter": one_iter, "infer": infer, "infer_b1": infer_b1}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", default="1,2", help="comma-separated thread counts")
    parser.add_argument("--repeat", type=positive_int, default=10)
    parser.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        print(json.dumps(_child(args.child, args.repeat)))
        return 0
    for t in thread_counts(parser, args.threads):
        row = run_child(__file__, t, ["--child", str(t), "--repeat", str(args.repeat)])
        print(json.dumps({k: round(v, 3) if isinstance(v, float) else v
                          for k, v in row.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
