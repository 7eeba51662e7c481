"""Reference solution, exercise 5 (ablations): remove double-Q, keep dueling.

The classic DQN target: the target network both picks and values the next action,
so its estimation noise is maximised over (van Hasselt et al. 2016: overestimation).
The other ablation is DUELING = False with the double-Q target of the template.
"""
import numpy as np

DUELING = True


def td_target(q_online_next, q_target_next, rewards, terminals, gamma):
    return rewards + gamma * (1.0 - terminals) * np.max(q_target_next, axis=-1)
