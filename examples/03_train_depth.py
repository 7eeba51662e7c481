"""Depth from raw frames alone: watch DispNet learn by view synthesis (a few minutes).

1. A scripted pilot flies the basic world; every 0.4 s the camera keeps a frame (the
   ground-truth depth is stored beside it, for the scorecard only).
2. DispNet + PoseNet train on triplets (previous, target, next): warp the neighbours
   into the target with the predicted depth and motion, compare the pixels.
3. Every few hundred iterations the example scores the depth against ground truth
   (abs rel, delta < 1.25) and adds a row RGB | predicted | GT to a picture.

    python examples/03_train_depth.py            # ~5 min on one core
    python examples/03_train_depth.py --smoke    # seconds: tiny run, checks it works

Outputs go to runs/example_depth/ (emerging.png: one row per checkpoint).
"""
import argparse
from pathlib import Path

import numpy as np

from minid3rqn.depth.data import Sequence, collect
from minid3rqn.depth.evaluate import DepthEstimator, comparison_picture, evaluate
from minid3rqn.depth.train import TrainConfig, Trainer


def as_sequence(data) -> Sequence:
    return Sequence(data["rgb"], data["flight"], data["K"], data["depth"], data["pose"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help="a tiny run, for the tests")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/example_depth")
    args = parser.parse_args()
    frames, test_frames, iterations, every = (60, 20, 4, 2) if args.smoke else (1500, 200, 1000, 250)

    print(f"1. collecting {frames} training and {test_frames} held-out frames (basic world)")
    train = as_sequence(collect("basic", frames, seed=args.seed, progress=False))
    test = as_sequence(collect("basic", test_frames, seed=args.seed + 1000, progress=False))
    print(f"   {len(train)} frames in {train.flight.max() + 1} flights, "
          f"{len(train.triplet_indices())} triplets")

    print(f"2. training DispNet + PoseNet for {iterations} iterations (batch 4)")
    cfg = TrainConfig(iterations=iterations, seed=args.seed, log_every=every)
    trainer = Trainer(train, cfg)
    shown = test.rgb[:1], test.depth[:1]
    rows = []

    def report(tr, row):
        est = DepthEstimator(tr.disp, 1.0)
        r = evaluate(est, test)
        print(f"   it {row['iteration']:5d}  loss {row['loss']:.4f}  abs rel {r['abs_rel']:.3f}"
              f"  delta<1.25 {r['a1']:.3f}")
        rows.append(est.predict(shown[0])[0])

    trainer.run(progress=False, callback=report)

    out = Path(args.out)
    n = len(rows)
    path = comparison_picture(np.repeat(shown[0], n, 0), np.stack(rows),
                              np.repeat(shown[1], n, 0), out / "emerging.png")
    print(f"3. one held-out frame, a row per report (RGB | predicted | GT): {path}")


if __name__ == "__main__":
    main()
