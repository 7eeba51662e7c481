"""Speed of the decision module: the D3RQN update against PyTorch, the framework's
inference rate, and the time to evaluate 2000 flights.

    python benchmarks/bench_rl.py                    # everything, 1 thread
    python benchmarks/bench_rl.py --threads 2 --repeat 20
    python benchmarks/bench_rl.py --only update

Measured (medians over ``--repeat`` runs after warm-ups, float32):

- ``update``: one D3RQN update as ``rl/agent.py`` runs it: batch 32 windows x 5 steps
  (6 depth frames each, 32x104), online and target nets over the window from a zero
  state, double-Q targets, masked Huber loss, backward, global-norm clipping, Adam.
  The torch side is the same network (conv 4x4 s2 / 4x4 s2 / 3x3 s1, LSTM 128,
  dueling heads) started from OUR weights; the script checks that both losses agree
  before timing, then times the two in alternating rounds. Target: ours <= 2x torch.
- ``framework_hz``: one flight (and 16 in lockstep), one step at a time: D3RQN step
  with carried state -> world step -> render RGB -> DispNet depth of the next frame
  (the paper's "whole framework", > 15 Hz on a GPU; target >= 100 Hz here), with the
  mean ms per step spent in the DispNet (``depth_ms``), the Q step (``q_ms``) and the
  rest (world, renderer). Uses ``minid3rqn/models/depth_basic.npz`` (else an untrained
  DispNet of the default architecture: same speed). ``--only framework_old`` runs the
  loop used before, which rendered and predicted every frame twice.
- ``eval_2000``: ``evaluate_policy`` with the D3RQN on 2000 flights x 50 steps, GT
  depth (and predicted depth if a depth model is shipped): seconds per model and
  scenario (target <= 120 s). ``--eval-flights`` scales it down for a quick look
  (the result is then extrapolated linearly and marked so). ``--eval-workers 1,2``
  times it with the flights' chunks spread over that many processes, one per core
  (``evaluate --workers``; each process runs ``--threads`` BLAS threads).
  ``cpu_seconds_per_2000``: the CPU time of all those processes (on a machine shared
  with other work, the wall time of two workers on two free cores is about half of it).
- The timed process keeps freed memory for reuse, as ``python -m minid3rqn`` does
  (minid3rqn/allocator.py); ``--default-malloc`` leaves glibc's allocator at its
  defaults (to measure what keeping freed memory is worth).
- ``--qnet FILE``: the framework and eval parts fly this Q-net instead of the shipped one
  (e.g. the distilled student, minid3rqn/models/d3rqn_distil.npz, with its wider LSTM).
- ``--ensemble N``: the framework and eval parts fly N copies of the D3RQN as an
  ensemble (``EnsemblePolicy``, docs/d3rqn.md section 10): N Q-net passes per step.
- ``--mirror``: each Q-net also flies the mirrored view (``evaluate --mirror``,
  ``fly --mirror``): twice the Q-net passes per step, one DispNet pass.

Threads: the script re-runs itself in a child with OMP/OPENBLAS/MKL_NUM_THREADS set
before NumPy loads (and ``torch.set_num_threads``). Output: one JSON line per part.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from _timing import load_torch, measure, median_ms, positive_int, thread_env

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def bench_update(repeat: int, threads: int, clock=time.perf_counter) -> dict:
    import numpy as np
    from minid3rqn.nets.qnet import QNetConfig
    from minid3rqn.rl.agent import Agent, AgentConfig
    from minid3rqn.rl.replay import SequenceBatch

    rng = np.random.default_rng(0)
    L, B = 5, 32
    batch = SequenceBatch(rng.random((L + 1, B, 1, 32, 104)).astype(np.float32),
                          rng.integers(5, size=(L, B)), rng.random((L, B)).astype(np.float32) * 3,
                          (rng.random((L, B)) < 0.1).astype(np.float32),
                          np.ones((L, B), np.float32))
    agent = Agent(QNetConfig(), AgentConfig(), rng=0)
    loss_ours, _ = agent.loss(batch)
    torch = load_torch(threads)
    out = {"part": "update", "threads": threads, "batch": f"{B}x{L}"}
    if torch is None:
        out["ours_ms"] = median_ms(lambda: agent.update(batch), repeat, warmup=2, clock=clock)
        out["torch_ms"] = None
        return out
    tnet, ttgt = _torch_qnet(agent.online, torch), _torch_qnet(agent.target, torch)
    opt = torch.optim.Adam(tnet.parameters(), lr=agent.config.lr)
    obs = torch.from_numpy(batch.obs)
    acts = torch.from_numpy(batch.actions)
    rew = torch.from_numpy(batch.rewards * agent.config.reward_scale)
    term = torch.from_numpy(batch.terminals)
    mask = torch.from_numpy(batch.mask)
    gamma = agent.config.gamma

    def torch_loss():
        q = tnet(obs)
        with torch.no_grad():
            qt = ttgt(obs)
            best = q[1:].argmax(-1, keepdim=True)
            y = rew + gamma * (1 - term) * qt[1:].gather(-1, best)[..., 0]
        qsa = q[:-1].gather(-1, acts[..., None])[..., 0]
        per = torch.nn.functional.huber_loss(qsa, y, reduction="none", delta=1.0)
        return (per * mask).sum() / mask.sum()

    ref = float(torch_loss().detach())
    if abs(ref - float(loss_ours.data)) > 1e-4 * max(1.0, abs(ref)):
        raise AssertionError(f"torch loss {ref} != ours {float(loss_ours.data)}")

    def torch_update():
        loss = torch_loss()
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(tnet.parameters(), agent.config.grad_clip)
        opt.step()

    # ours and torch alternating, so the machine's load hits both alike
    t = measure({"ours": lambda: agent.update(batch), "torch": torch_update}, repeat,
                warmup=2, clock=clock)
    out["ours_ms"], out["torch_ms"] = t["ours"], t["torch"]
    out["ratio"] = out["ours_ms"] / out["torch_ms"]
    out["losses_agree"] = True
    return out


def _torch_qnet(net, torch):
    """The same QNet in torch, with our weights copied in."""
    nn = torch.nn
    cfg = net.config

    class TQ(nn.Module):
        def __init__(self):
            super().__init__()
            convs, c = [], cfg.in_channels
            for out, k, s in cfg.convs:
                convs.append(nn.Conv2d(c, out, k, s))
                c = out
            self.convs = nn.ModuleList(convs)
            self.lstm = nn.LSTM(net.n_features, cfg.width)
            self.value = nn.Linear(cfg.width, 1)
            self.adv = nn.Linear(cfg.width, cfg.n_actions)

        def forward(self, x):
            T, B = x.shape[:2]
            z = x.reshape((T * B,) + tuple(x.shape[2:]))
            for conv in self.convs:
                z = torch.relu(conv(z))
            z = z.reshape(T, B, -1)
            z, _ = self.lstm(z)
            a = self.adv(z)
            return self.value(z) + a - a.mean(-1, keepdim=True)

    t = TQ()
    with torch.no_grad():
        for conv, ours in zip(t.convs, net.convs):
            conv.weight.copy_(torch.from_numpy(ours.weight.data))
            conv.bias.copy_(torch.from_numpy(ours.bias.data))
        t.lstm.weight_ih_l0.copy_(torch.from_numpy(net.core.weight_ih.data))
        t.lstm.weight_hh_l0.copy_(torch.from_numpy(net.core.weight_hh.data))
        t.lstm.bias_ih_l0.copy_(torch.from_numpy(net.core.bias.data))
        t.lstm.bias_hh_l0.zero_()
        t.value.weight.copy_(torch.from_numpy(net.value.weight.data))
        t.value.bias.copy_(torch.from_numpy(net.value.bias.data))
        t.adv.weight.copy_(torch.from_numpy(net.advantage.weight.data))
        t.adv.bias.copy_(torch.from_numpy(net.advantage.bias.data))
    return t


def _qnet_model(ensemble: int = 1, qnet: str | None = None, mirror: bool = False):
    """The shipped D3RQN (else an untrained one: same speed), or the file ``qnet``;
    ``ensemble`` > 1: that many copies of it flying as an ``EnsemblePolicy`` (the speed
    does not depend on the weights); ``mirror``: each with its mirrored twin, as
    ``evaluate --mirror`` flies them."""
    from minid3rqn.rl.mirror import MirroredPolicy
    from minid3rqn.rl.models import SHIPPED_QNET
    from minid3rqn.rl.policies import EnsemblePolicy, QNetPolicy
    from minid3rqn.nets.qnet import QNet, QNetConfig

    def one():
        if qnet:
            return QNetPolicy.load(qnet, "D3RQN"), str(qnet)
        if SHIPPED_QNET.exists():
            return QNetPolicy.load(SHIPPED_QNET, "D3RQN"), str(SHIPPED_QNET)
        return QNetPolicy(QNet(QNetConfig(), rng=0), "D3RQN (untrained)"), "untrained"
    members = [one() for _ in range(ensemble)]
    name = members[0][1] if ensemble == 1 else f"ensemble of {ensemble} x {members[0][1]}"
    policies = [m for m, _ in members]
    if mirror:
        policies += [MirroredPolicy(m) for m in policies]
        name += ", with the mirror image"
    return (policies[0] if len(policies) == 1 else EnsemblePolicy(policies)), name


class _TimedEstimator:
    """Wraps a DepthEstimator to add up the time spent in ``predict``."""

    def __init__(self, est):
        self.est, self.seconds = est, 0.0
        # What an env may ask before it calls predict: whether to hand it the frames before
        # (a two-frame or cost-volume DispNet) and the motion since (a cost volume).
        self.needs_previous = getattr(est, "needs_previous", False)
        self.cost_planes = getattr(est, "cost_planes", 0)

    def predict(self, rgb, prev=None, motion=None):
        t = time.perf_counter()
        out = (self.est.predict(rgb) if prev is None else
               self.est.predict(rgb, prev=prev, motion=motion))
        self.seconds += time.perf_counter() - t
        return out


def bench_framework(repeat: int, threads: int, n_flights: int = 1, ensemble: int = 1,
                    depth_model: str | None = None, flip: bool = False,
                    qnet: str | None = None, mirror: bool = False) -> dict:
    """Render -> DispNet -> Q-net step -> world step for ``n_flights`` flights in lockstep
    (batched over flights): frames per second (= Hz per flight when n_flights = 1).

    One step is ``policy.act`` on the current depth, then ``DroneEnv.step``: the world
    step (arc, clearance checks, reward, resets) and the next observation (render RGB,
    DispNet depth). Each frame is rendered and its depth predicted once
    (``rendered_twice`` runs a loop that re-renders and re-predicts the current pose
    before acting, doing the perception twice per step, for comparison).
    ``depth_model``: another DispNet file (e.g. one of the transfer worlds').
    ``flip``: the DispNet's test-time flip (``--flip-tta``: two DispNet passes per frame).
    ``qnet``: another Q-net file (``--qnet``; e.g. a wider LSTM) instead of the shipped one.
    ``mirror``: each Q-net with its mirror image (``--mirror``)."""
    import numpy as np
    from minid3rqn.rl.models import shipped_depth_model, load_depth_estimator
    from minid3rqn.world import DroneEnv
    policy, model = _qnet_model(ensemble, qnet, mirror)
    depth_path = Path(depth_model) if depth_model else shipped_depth_model("basic")
    if depth_path.exists():
        est, depth_name = load_depth_estimator(depth_path, flip), f"DispNet {depth_path.name}"
    else:   # the speed does not depend on the weights: time an untrained DispNet
        from minid3rqn.depth.evaluate import DepthEstimator
        from minid3rqn.depth.flip import FlipAveraged
        from minid3rqn.nets.dispnet import DispNet
        est = DepthEstimator(DispNet())
        est = FlipAveraged(est) if flip else est
        depth_name = "DispNet (default architecture, untrained)"
    if flip:
        depth_name += ", test-time flip"
    timed = _TimedEstimator(est)
    env = DroneEnv("basic", n_flights, seed=0, observation="pred", depth_model=timed,
                   autoreset=True)
    obs = {"depth": env.reset()[0], "started": np.ones(n_flights, bool)}
    policy.reset(env)
    q_seconds = [0.0]

    def one_step():
        t = time.perf_counter()
        a = policy.act(obs["depth"], started=obs["started"])
        q_seconds[0] += time.perf_counter() - t
        obs["depth"], _, terminated, truncated, _ = env.step(a)
        obs["started"] = terminated | truncated

    for _ in range(5):
        one_step()
    timed.seconds, q_seconds[0] = 0.0, 0.0
    n, t = 0, time.perf_counter()          # at least 3 s (steps are short: a few ms)
    while n < max(20, repeat * 5) or time.perf_counter() - t < 3.0:
        one_step()
        n += 1
    dt = (time.perf_counter() - t) / n
    depth_ms, q_ms = 1000 * timed.seconds / n, 1000 * q_seconds[0] / n
    return {"part": "framework_hz", "threads": threads, "flights": n_flights,
            "frames_per_s": n_flights / dt, "step_ms": 1000 * dt,
            "depth_ms": depth_ms, "q_ms": q_ms,
            "world_render_ms": 1000 * dt - depth_ms - q_ms,
            "depth": depth_name, "model": model,
            "note": f"Q step + world step + render + depth, {n_flights} flight(s) in "
                    f"lockstep; means over {n} steps"}


def bench_framework_rendered_twice(repeat: int, threads: int, n_flights: int = 1) -> dict:
    """The loop this benchmark ran before: render and predict the current pose, act,
    then ``DroneEnv.step`` (which renders and predicts the next pose again): two
    renders and two DispNet passes per step. Kept to compare with old figures."""
    from minid3rqn.rl.models import shipped_depth_model, load_depth_estimator
    from minid3rqn.world import DroneEnv, render_batch
    policy, model = _qnet_model()
    est = load_depth_estimator(shipped_depth_model("basic"))
    env = DroneEnv("basic", n_flights, seed=0, observation="pred", depth_model=est,
                   autoreset=True)
    env.reset()
    policy.reset(env)

    def one_step():
        rgb, gt = render_batch(env.batch, env.poses, env.camera)
        a = policy.act(est.predict(rgb))
        env.step(a)

    n = max(20, repeat * 5)
    for _ in range(5):
        one_step()
    t = time.perf_counter()
    for _ in range(n):
        one_step()
    dt = (time.perf_counter() - t) / n
    return {"part": "framework_hz_rendered_twice", "threads": threads, "flights": n_flights,
            "frames_per_s": n_flights / dt, "step_ms": 1000 * dt, "model": model,
            "note": "the old loop: perception twice per step"}


def bench_eval(flights: int, threads: int, workers: int = 1, ensemble: int = 1,
               qnet: str | None = None, mirror: bool = False) -> list:
    from minid3rqn.rl.models import shipped_depth_model, load_depth_estimator
    from minid3rqn.rl.evaluate import evaluate_policy
    policy, model = _qnet_model(ensemble, qnet, mirror)
    outs = []
    modes = [("gt", None)]
    if shipped_depth_model("basic").exists():
        modes.append(("pred", load_depth_estimator(shipped_depth_model("basic"))))
    import resource

    def cpu_seconds():                 # this process and its reaped workers
        return sum(resource.getrusage(who).ru_utime + resource.getrusage(who).ru_stime
                   for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    for depth, est in modes:
        cpu = cpu_seconds()
        res = evaluate_policy(policy, "basic", n_flights=flights, depth=depth,
                              depth_estimator=est, progress=False, workers=workers)
        cpu = cpu_seconds() - cpu
        outs.append({"part": "eval_2000", "threads": threads, "workers": workers,
                     "depth": depth,
                     "flights": flights, "seconds": res.seconds,
                     "seconds_per_2000": res.seconds * 2000 / flights,
                     "cpu_seconds_per_2000": cpu * 2000 / flights,
                     "extrapolated": flights != 2000, "rate": res.rate, "model": model})
    return outs


def child(args) -> None:
    sys.path.insert(0, ROOT)
    from minid3rqn.allocator import keep_freed_memory
    kept = False if args.default_malloc else keep_freed_memory()
    print(json.dumps({"allocator": "freed memory kept" if kept else "glibc defaults"}),
          flush=True)
    parts = args.only.split(",") if args.only else ["update", "framework", "eval"]
    if "update" in parts:
        print(json.dumps(bench_update(args.repeat, args.threads)), flush=True)
    if "framework" in parts:
        for n_flights in (1, 16):
            print(json.dumps(bench_framework(args.repeat, args.threads, n_flights,
                                             args.ensemble, args.depth_model,
                                             args.flip_tta, args.qnet, args.mirror)),
                  flush=True)
    if "framework_old" in parts:
        for n_flights in (1, 16):
            print(json.dumps(bench_framework_rendered_twice(args.repeat, args.threads,
                                                            n_flights)), flush=True)
    if "eval" in parts:
        for workers in [int(w) for w in args.eval_workers.split(",")]:
            for row in bench_eval(args.eval_flights, args.threads, workers, args.ensemble,
                                  args.qnet, args.mirror):
                print(json.dumps(row), flush=True)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--threads", type=positive_int, default=1)
    p.add_argument("--repeat", type=positive_int, default=10)
    p.add_argument("--only", default=None,
                   help="comma list of update,framework,framework_old,eval")
    p.add_argument("--eval-flights", type=int, default=2000)
    p.add_argument("--eval-workers", default="1",
                   help="comma list of process counts for the eval part, e.g. 1,2")
    p.add_argument("--ensemble", type=int, default=1,
                   help="framework and eval parts: fly N copies of the D3RQN as an ensemble")
    p.add_argument("--depth-model", default=None,
                   help="framework part: this DispNet file instead of the shipped one")
    p.add_argument("--flip-tta", action="store_true",
                   help="framework part: the DispNet's test-time flip (two passes per frame)")
    p.add_argument("--qnet", default=None,
                   help="framework and eval parts: this Q-net file instead of the shipped one")
    p.add_argument("--mirror", action="store_true",
                   help="framework and eval parts: each Q-net also flies the mirrored view "
                        "(evaluate --mirror): two Q-net passes per step")
    p.add_argument("--default-malloc", action="store_true",
                   help="leave glibc's allocator at its defaults instead of keeping freed "
                        "memory as python -m minid3rqn does (minid3rqn/allocator.py)")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child:
        child(args)
        return
    cmd = [sys.executable, os.path.abspath(__file__), "--child", "--threads", str(args.threads),
           "--repeat", str(args.repeat), "--eval-flights", str(args.eval_flights),
           "--eval-workers", args.eval_workers, "--ensemble", str(args.ensemble)]
    if args.only:
        cmd += ["--only", args.only]
    if args.depth_model:
        cmd += ["--depth-model", args.depth_model]
    if args.flip_tta:
        cmd += ["--flip-tta"]
    if args.mirror:
        cmd += ["--mirror"]
    if args.default_malloc:
        cmd += ["--default-malloc"]
    if args.qnet:
        if not Path(args.qnet).is_file():
            p.error(f"--qnet: expected a Q-net .npz file; got {args.qnet!r} (not a file)")
        cmd += ["--qnet", args.qnet]
    sys.exit(subprocess.run(cmd, env=thread_env(args.threads)).returncode)


if __name__ == "__main__":
    main()
