"""Deep Q-learning for obstacle avoidance: replay of sequences, the double-Q agent, the
training loop, batched evaluation (success rate with a Wilson interval), baselines.

    flights.py   many flights at once over ``world`` (GT or predicted depth)
    replay.py    episodic replay sampled as windows that never cross episodes
    agent.py     epsilon-greedy acting with recurrent state, double-Q update
    train.py     the loop, checkpoints and exact resume, learning curves
    distill.py   ours: a student on predicted depth learns a GT-depth teacher's Q-values
    evaluate.py  success rate over N flights, Wilson 95% interval (by flight and by world)
    policies.py  Straight, Random, Reactive, Oracle, QNetPolicy, EnsemblePolicy (ours)
    fly.py       the main job: GIF + success rate with the shipped model
    commands.py  CLI hooks (train-agent, evaluate, fly, reproduce)
"""
from .agent import Agent, AgentConfig, double_q_targets
from .evaluate import EvalResult, clustered_interval, evaluate_policy, wilson_interval
from .flights import Flights, FlightsConfig
from .policies import (OraclePolicy, QNetPolicy, RandomPolicy, ReactivePolicy, StraightPolicy)
from .replay import EpisodeReplay, SequenceBatch
from .train import TrainConfig, Trainer, train
from .distill import Distiller, LabelledReplay
