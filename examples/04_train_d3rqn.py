"""Train the paper's D3RQN (dueling double deep recurrent Q-network) on GT depth.

The loop is minid3rqn/rl/train.py: 16 flights stepped together, an episodic replay
sampled as 5-step windows, double-Q targets, a target net refreshed every 300 updates.
The Table-5 run (budget B) took 29 min on a 2-core machine shared with four other
jobs:

    python -m minid3rqn train-agent --variant d3rqn --seed 0 --steps 60000 \
        --learning-starts 5000 --eps-decay-steps 50000 --replay-capacity 100000

The shipped model was trained longer (240k transitions at 2 updates per step, 30 min
on one core, 0.949 on GT depth), then fine-tuned for 20k transitions on predicted
depth (docs/results.md):

    python -m minid3rqn train-agent --variant d3rqn --seed 0 --steps 240000 \
        --learning-starts 5000 --eps-decay-steps 100000 --replay-capacity 100000 \
        --set updates_per_step=2.0

    python examples/04_train_d3rqn.py [--smoke] [--out DIR]

``--smoke`` runs a few hundred steps with a tiny network (seconds); the learning curve
(CSV + PNG) and the model land in DIR. Without it, this script (budget B) took 14 min
(832 s) alone on an idle 2-core machine (`python benchmarks/bench_examples.py --only 04`).
"""
import argparse
from pathlib import Path

from minid3rqn.rl.train import SMOKE, TrainConfig, train


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--smoke", action="store_true")
    p.add_argument("--out", default="runs/example_d3rqn")
    args = p.parse_args()
    if args.smoke:
        cfg = TrainConfig(**SMOKE)
    else:
        cfg = TrainConfig(steps=60_000, learning_starts=5_000, eps_decay_steps=50_000,
                          replay_capacity=100_000, updates_per_step=4.0)
    print(f"training {cfg.variant}: {cfg.steps} transitions, {cfg.n_envs} flights at "
          f"once, window {cfg.window()}, batch {cfg.batch_size}, gamma {cfg.agent.gamma}")
    run = train(cfg, Path(args.out), progress=not args.smoke)
    for row in run.curve[-3:]:
        print(f"  steps {row['steps']:>6}  eps {row['epsilon']:.2f}  return {row['return']:6.2f}"
              f"  success {row['success']:.2f}  loss {row['loss']:.4f}")
    print(f"model: {Path(args.out) / 'model.npz'}   curve: {Path(args.out) / 'curve.png'}")


if __name__ == "__main__":
    main()
