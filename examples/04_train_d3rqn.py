# %% [markdown]
# # 04: Train the paper's D3RQN (dueling double deep recurrent Q-network) on GT depth
#
# The loop is minid3rqn/rl/train.py: 16 flights stepped together, an episodic replay
# sampled as 5-step windows, double-Q targets, a target net refreshed every 300 updates.
#
# By default a short run (18,000 transitions, 64 LSTM units, 1,501 updates; under 2
# minutes on one core) prints the learning curve every 2,000 transitions, measured on the
# training flights (epsilon-greedy). While epsilon falls, and for a while after, the
# flights last 9 to 13 steps of 50 (a random pilot's 11); then they get longer, to 20-22
# steps at 18,000 transitions, and 10-15% of them succeed (50 steps without a collision;
# the figures of two machines, which differ by CPU: docs/exercises/README.md). Learning
# has only begun: the exercises' runs (40,000 transitions, epsilon falling over 25,000)
# fly 0.62-0.70 of their 200 test flights.
#
# ``--full`` is 60,000 transitions with the paper's network, four updates per step of the
# 16 flights: the run docs/results.md quotes under Table 5 (0.871 on GT depth, 2000
# flights, seed 12345). It took 14 min (832 s) alone on an idle 2-core machine, 29 min on
# one shared with four other jobs:
#
#     python -m minid3rqn train-agent --variant d3rqn --seed 0 --steps 60000 \
#         --learning-starts 5000 --eps-decay-steps 50000 --replay-capacity 100000
#
# The shipped model was trained longer (240k transitions at 2 updates per step, 30 min
# on one core, 0.949 on GT depth), then fine-tuned for 20k transitions on predicted
# depth (docs/results.md):
#
#     python -m minid3rqn train-agent --variant d3rqn --seed 0 --steps 240000 \
#         --learning-starts 5000 --eps-decay-steps 100000 --replay-capacity 100000 \
#         --set updates_per_step=2.0
#
#     python examples/04_train_d3rqn.py [--full | --smoke] [--out runs/examples/04_train_d3rqn]
#
# The learning curve (CSV + PNG) and the model land in the --out folder (the run's
# checkpoint, which holds the whole replay, is removed); ``--smoke`` runs a few hundred
# steps with a tiny network (seconds).

# %%
"""Train the paper's D3RQN (dueling double deep recurrent Q-network) on GT depth."""
import argparse
import sys
from pathlib import Path

from minid3rqn.rl.train import SMOKE, TrainConfig, train

SHORT = dict(steps=18_000, learning_starts=2_000, eps_decay_steps=8_000,
             replay_capacity=18_000, hidden=64, updates_per_step=1.5, checkpoint_every=10 ** 9)
FULL = dict(steps=60_000, learning_starts=5_000, eps_decay_steps=50_000,
            replay_capacity=100_000, updates_per_step=4.0)


# %%
def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--full", action="store_true", help="60,000 transitions, the paper's network (about 14 min)")
    p.add_argument("--smoke", action="store_true", help="a few hundred steps (tests)")
    p.add_argument("--out", default="runs/examples/04_train_d3rqn",
                   help="folder for the model and the learning curve")
    args = p.parse_args([] if "ipykernel" in sys.modules else None)
    cfg = TrainConfig(**(SMOKE if args.smoke else FULL if args.full else SHORT))
    print(f"training {cfg.variant}: {cfg.steps} transitions, {cfg.n_envs} flights at "
          f"once, window {cfg.window()}, batch {cfg.batch_size}, gamma {cfg.agent.gamma}")
    run = train(cfg, Path(args.out), progress=False)
    (Path(args.out) / "checkpoint.npz").unlink(missing_ok=True)    # the replay: 64-330 MB
    print(f"{'transitions':>11} {'updates':>8} {'epsilon':>8} {'steps/50':>9} {'success':>8} "
          f"{'loss':>8}")
    for row in run.curve:
        print(f"{row['steps']:>11} {row['updates']:>8} {row['epsilon']:>8.2f} "
              f"{row['length']:>9.1f} {row['success']:>8.2f} {row['loss']:>8.4f}")
    print(f"(on the training flights, epsilon-greedy) model: {Path(args.out) / 'model.npz'}   "
          f"curve: {Path(args.out) / 'curve.png'}")


# %%
if __name__ == "__main__":
    main()
