"""Deep Q-learning for obstacle avoidance: replay of sequences, the double-Q agent, the
training loop, batched evaluation (success rate with a Wilson interval), baselines.

    observe.py   what a Q-net reads of the env's depth: encoded, then stacked
    replay.py    episodic replay sampled as windows that never cross episodes
    agent.py     epsilon-greedy acting with recurrent state, double-Q update
    train.py     the loop (TrainConfig, train), checkpoints and exact resume
    evaluate.py  success rate over N flights, Wilson 95% interval (by flight and by world)
    policies.py  Straight, Random, Reactive, Oracle, QNetPolicy, EnsemblePolicy (ours)
    models.py    model files: the shipped ones, a file's actions and camera, policies by name
    fly.py       the main job: GIF + success rate with the shipped model
    reproduce.py Tables 5 and 6 end to end; our distilled recipe
Ours, built on the above:
    distill.py   a student on predicted depth learns a GT-depth teacher's Q-values
    mirror.py    the mirror image: a policy flying the mirrored view; mirrored windows
    pool.py      evaluations pooled by world; A against B on the same worlds
    commands.py  the command line (train-agent, distil, evaluate, fly, reproduce)
"""
from .agent import Agent, AgentConfig, double_q_targets
from .evaluate import EvalResult, clustered_interval, evaluate_policy, wilson_interval
from .observe import encode_depth
from .policies import OraclePolicy, QNetPolicy, RandomPolicy, ReactivePolicy, StraightPolicy
from .replay import EpisodeReplay, SequenceBatch
from .train import TrainConfig, train
