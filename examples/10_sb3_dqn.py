# %% [markdown]
# # 10: the world from an outside library (Stable-Baselines3's DQN)
#
# The world is a Gymnasium environment, ``"minid3rqn/Drone-v0"`` (``minid3rqn/gym.py``),
# so any Gymnasium library can learn in it. Here Stable-Baselines3's DQN learns on GT
# depth, seen as our feed-forward Q-nets see it: encoded into [0, 1] and the last 5
# frames stacked (``minid3rqn.gym.qnet_input``), through the paper's conv stack as its
# feature extractor (SB3's NatureCNN cannot take a 32x104 frame: its 8x8 stride-4 and
# 4x4 stride-2 layers leave too little of it). Then our DDQN learns from the same number
# of transitions, and both are scored by our own ``evaluate`` on the test worlds.
#
#     pip install -e ".[gym]" stable-baselines3 torch
#     python examples/10_sb3_dqn.py [--steps 20000] [--flights 2000] [--seed 0]
#     python examples/10_sb3_dqn.py --smoke        # a few hundred transitions
#
# The two learners share the settings that are settings of both: discount 0.99, Adam at
# 3e-4, batches of 32, one update per 4 transitions, a target net refreshed every 300
# updates, the Huber loss, gradients clipped to norm 10, rewards x 0.1, epsilon from 1 to
# 0.05 over half the budget, learning from transition 2,000, the conv stack and a fully
# connected layer of 128. They differ where the libraries do: SB3's DQN takes the max of
# the target net (ours: double Q, the online net's choice), flies one drone (ours: 16 at
# once) and replays single transitions (ours: windows of 1 step here, the same thing).

# %%
import argparse
import sys
from pathlib import Path

import numpy as np

try:
    import gymnasium
    import torch
    from stable_baselines3 import DQN
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
except ImportError as e:
    print(f"examples/10_sb3_dqn.py needs Gymnasium, Stable-Baselines3 and PyTorch "
          f"({e.name} is missing); install them with\n"
          f"    pip install -e \".[gym]\" stable-baselines3 torch")
    sys.exit(0)

import minid3rqn.gym as mgym
from minid3rqn.nets.qnet import QNetConfig
from minid3rqn.rl.agent import FrameStacker
from minid3rqn.rl.evaluate import TEST_WORLDS, evaluate_policy
from minid3rqn.rl.models import load_qnet_policy
from minid3rqn.rl.observe import encode_depth
from minid3rqn.rl.policies import Policy
from minid3rqn.rl.train import TrainConfig, run_seeds, train

STACK = 5


# %% [markdown]
# ## The paper's conv stack as SB3's feature extractor
#
# The three valid convolutions of ``nets/qnet.py`` (4x4 stride 2, 4x4 stride 2, 3x3
# stride 1; 4, 8, 8 channels; ReLU after each): 32x104 -> 4x22, 704 features. SB3's
# Q-network then adds one hidden layer of 128 units and the output layer, as our DDQN.

# %%
class PaperConvs(BaseFeaturesExtractor):
    def __init__(self, observation_space, convs=None):
        convs = convs or QNetConfig().convs
        layers, c = [], observation_space.shape[0]
        for out, k, s in convs:
            layers += [torch.nn.Conv2d(c, out, k, s), torch.nn.ReLU()]
            c = out
        body = torch.nn.Sequential(*layers, torch.nn.Flatten())
        with torch.no_grad():
            n = body(torch.zeros((1,) + observation_space.shape)).shape[1]
        super().__init__(observation_space, features_dim=n)
        self.body = body

    def forward(self, obs):
        return self.body(obs)


# %% [markdown]
# ## SB3's DQN on the registered environment
#
# ``gymnasium.make`` builds one drone in the training worlds; ``qnet_input`` encodes and
# stacks its depth; the reward is scaled as our agent scales it.

# %%
def train_sb3(steps: int, seed: int, learning_starts: int, out: Path):
    env = gymnasium.make(mgym.ENV_ID, scenario="basic", observation="depth",
                         worlds="train", seed=run_seeds(seed)[1])
    env = gymnasium.wrappers.TransformReward(mgym.qnet_input(env, STACK), lambda r: 0.1 * r)
    model = DQN("MlpPolicy", env, learning_rate=3e-4, buffer_size=steps, batch_size=32,
                gamma=0.99, train_freq=4, gradient_steps=1, learning_starts=learning_starts,
                target_update_interval=1200, exploration_fraction=0.5,
                exploration_initial_eps=1.0, exploration_final_eps=0.05, max_grad_norm=10,
                policy_kwargs=dict(features_extractor_class=PaperConvs, net_arch=[128]),
                seed=seed, device="cpu", verbose=0)
    model.learn(total_timesteps=steps)
    model.save(out / "sb3_dqn")
    return model


# %% [markdown]
# ## Scored by our own evaluation
#
# A policy of our protocol (``reset(env)``, ``act(depth)``) around the SB3 model: the
# same two steps in front of it (encode, stack 5), then its greedy action.

# %%
class SB3Policy(Policy):
    name = "SB3-DQN"

    def __init__(self, model):
        self.model = model

    def reset(self, env):
        self.n = env.n_envs
        self.stacker = FrameStacker(self.n, STACK, env.frame_shape)
        self.fresh = True

    def act(self, obs, started=None):
        frames = encode_depth(obs)
        if self.fresh:
            self.stacker.reset(np.arange(self.n), frames)
            self.fresh = False
        else:
            self.stacker.push(frames)
        actions, _ = self.model.predict(self.stacker.obs, deterministic=True)
        return np.asarray(actions, np.int64)


# %% [markdown]
# ## Run it
#
# Both learn from ``--steps`` transitions; both fly the same ``--flights`` test flights
# (evaluation seed 271828, ``evaluate``'s test worlds), on GT depth.

# %%
def main(argv=None):
    p = argparse.ArgumentParser(description="SB3's DQN and our DDQN on the same world")
    p.add_argument("--steps", type=int, default=20_000, help="transitions each learns from")
    p.add_argument("--flights", type=int, default=2000, help="test flights each flies")
    p.add_argument("--seed", type=int, default=0, help="seeds both learners")
    p.add_argument("--out", default="runs/examples/10_sb3_dqn", help="where both land")
    p.add_argument("--smoke", action="store_true", help="a few hundred transitions")
    args = p.parse_args([] if argv is None and "ipykernel" in sys.modules else argv)
    if args.smoke:
        args.steps, args.flights = 256, 8
    start = min(2_000, args.steps // 4)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    sb3 = train_sb3(args.steps, args.seed, start, out)
    ours = TrainConfig(variant="ddqn", stack=STACK, steps=args.steps, seed=args.seed,
                       learning_starts=start, eps_decay_steps=args.steps // 2,
                       replay_capacity=max(args.steps, 64 * 16), log_every=2_000,
                       checkpoint_every=args.steps, **({"n_envs": 4, "hidden": 16}
                                                       if args.smoke else {}))
    train(ours, out / "ddqn", progress=False)
    print(f"{args.steps} transitions each; {args.flights} test flights (seed {TEST_WORLDS}), "
          f"GT depth")
    for policy in (SB3Policy(sb3), load_qnet_policy(out / "ddqn" / "model.npz")):
        res = evaluate_policy(policy, "basic", args.flights, TEST_WORLDS, progress=False)
        print(res.line(), flush=True)


if __name__ == "__main__":
    main()
