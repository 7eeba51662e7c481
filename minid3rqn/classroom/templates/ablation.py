"""Exercise 5: ablations. This file is the one place to change.

D3RQN = Dueling + Double + Deep Recurrent Q-Network. Take one ingredient out at a time
and see what it was worth:

  * DUELING = False: the head is one fully connected layer to the Q-values instead of
    a value stream V plus an advantage stream A (Q = V + A - mean A).
  * td_target: the learning target for Q(o_t, a_t). Double Q-learning (the paper) lets
    the online network PICK the next action and the target network VALUE it. Remove
    double-Q by writing the classic DQN target, where the target network does both:
        y = r + gamma * (1 - terminal) * max_a Q_target(o_{t+1}, a)

    python -m minid3rqn check ablation
    python -m minid3rqn exercise ablation               (your ablation)
    python -m minid3rqn exercise ablation --baseline    (full D3RQN, to compare)
"""
import numpy as np

DUELING = True


def td_target(q_online_next, q_target_next, rewards, terminals, gamma):
    """The TD target y for every step of a batch of replayed windows.

    Args:
        q_online_next: (L, B, A) Q-values of the next observations, online network.
        q_target_next: (L, B, A) the same from the target network.
        rewards: (L, B) rewards.
        terminals: (L, B) 1.0 where the step ended in a collision (no next state), else 0.
        gamma: discount factor (0.99).

    Returns:
        (L, B) targets y.
    """
    best = np.argmax(q_online_next, axis=-1)                          # online net picks
    value = np.take_along_axis(q_target_next, best[..., None], axis=-1)[..., 0]  # target values
    return rewards + gamma * (1.0 - terminals) * value
